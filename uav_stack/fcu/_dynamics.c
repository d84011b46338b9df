/* The virtual FCU's multirotor step for a few vehicles, compiled (uav_stack/fcu/dynamics.py).
 *
 * Why: a virtual UAV advances its one vehicle about 50 times a second. In Python the step
 * (MultirotorArray._step_scalar) was the largest single function of a UAV's main thread
 * (7-10 % of it, benchmarks/uav_profile.py), mostly the interpreter working through ~60 float
 * operations and converting ~25 numpy arrays to lists and back on every call. Here the same
 * equations run on the arrays' memory in place.
 *
 * The equations, their order and every branch are those of _step_scalar, line for line, with
 * Python's semantics where C's differ: min/max keep the first argument unless the second is
 * strictly smaller/larger (so NaN propagates as in Python), and float % takes the sign of the
 * divisor. tests/test_fcu_dynamics.py flies both and asserts they agree.
 *
 * Built at install when a C compiler and Python's headers are there (setup.py, optional); without
 * them dynamics.py uses the Python step.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>
#include "_pyfloat.h"

#define G 9.80665
#define PYMIN(a, b) ((b) < (a) ? (b) : (a))
#define PYMAX(a, b) ((b) > (a) ? (b) : (a))

static const double TWO_PI = 2.0 * M_PI;

/* The arrays step() reads and writes, by attribute name, with their kind:
 * 'v': (n, 3) float64, 'f': (n,) float64, 'b': (n,) bool. */
typedef struct { const char *name; char kind; } Field;

enum {
    F_POS, F_VEL, F_ACC, F_POS_SP, F_VEL_FF, F_WIND,
    F_ARMED, F_LANDED, F_GROUND_Z,
    F_VXY_MAX, F_VZ_UP, F_VZ_DN, F_ACC_HOR, F_TILT_ACC, F_YAW_RATE_MAX,
    F_YAW_SP, F_YAW_RATE_SP, F_YAW, F_YAW_RATE, F_ROLL, F_PITCH, F_ROLL_RATE, F_PITCH_RATE,
    F_BATTERY, F_ENDURANCE_S,
    N_FIELDS
};

static const Field FIELDS[N_FIELDS] = {
    {"pos", 'v'}, {"vel", 'v'}, {"acc", 'v'}, {"pos_sp", 'v'}, {"vel_ff", 'v'}, {"wind", 'v'},
    {"armed", 'b'}, {"landed", 'b'}, {"ground_z", 'f'},
    {"vxy_max", 'f'}, {"vz_up", 'f'}, {"vz_dn", 'f'}, {"acc_hor", 'f'}, {"tilt_acc", 'f'}, {"yaw_rate_max", 'f'},
    {"yaw_sp", 'f'}, {"yaw_rate_sp", 'f'}, {"yaw", 'f'}, {"yaw_rate", 'f'}, {"roll", 'f'}, {"pitch", 'f'},
    {"roll_rate", 'f'}, {"pitch_rate", 'f'},
    {"battery", 'f'}, {"endurance_s", 'f'},
};

static PyObject *field_names[N_FIELDS];
static PyObject *name_n;  /* "n", interned once like the field names */

/* The arrays of one MultirotorArray, exported once and kept: getting ~25 numpy buffers anew on
 * every call cost more than the step itself. An attribute that now holds another array (the
 * vectorised path assigns new ones) is exported again; a kept export also stops numpy from
 * resizing the array under us. */
typedef struct {
    PyObject_HEAD
    Py_ssize_t n;               /* vehicles the kept views were checked for */
    PyObject *objs[N_FIELDS];   /* borrowed: each stays alive through its view */
    Py_buffer views[N_FIELDS];
} Stepper;

static void stepper_forget(Stepper *st, int k) {
    if (st->objs[k] != NULL) {
        PyBuffer_Release(&st->views[k]);
        st->objs[k] = NULL;
    }
}

/* Every field of `obj` as a writable C-contiguous buffer of the right type and length. */
static int stepper_views(Stepper *st, PyObject *obj, Py_ssize_t n) {
    for (int k = 0; k < N_FIELDS; k++) {
        PyObject *arr = PyObject_GetAttr(obj, field_names[k]);
        if (arr == NULL) return -1;
        if (arr == st->objs[k] && st->n == n) {  /* the array we hold a view of */
            Py_DECREF(arr);
            continue;
        }
        stepper_forget(st, k);
        int rc = PyObject_GetBuffer(arr, &st->views[k], PyBUF_WRITABLE | PyBUF_FORMAT | PyBUF_C_CONTIGUOUS);
        const Field *f = &FIELDS[k];
        int ok = 0;
        if (rc == 0) {
            const char *fmt = st->views[k].format ? st->views[k].format : "B";
            ok = f->kind == 'b'
                ? (strcmp(fmt, "?") == 0 && st->views[k].len == n)
                : (strcmp(fmt, "d") == 0 && st->views[k].len == (Py_ssize_t)sizeof(double) * n * (f->kind == 'v' ? 3 : 1));
            if (!ok) PyBuffer_Release(&st->views[k]);
        }
        if (!ok) {  /* read-only, strided, of another type or size: say which array */
            Py_DECREF(arr);
            PyErr_Clear();
            PyErr_Format(PyExc_ValueError, "MultirotorArray.%s must be a writable C-contiguous %s array of %zd vehicles",
                         f->name, f->kind == 'b' ? "bool" : "float64", n);
            return -1;
        }
        st->objs[k] = arr;
        Py_DECREF(arr);  /* the view holds its own reference */
    }
    st->n = n;
    return 0;
}

static void stepper_dealloc(Stepper *st) {
    for (int k = 0; k < N_FIELDS; k++) stepper_forget(st, k);
    Py_TYPE(st)->tp_free((PyObject *)st);
}

PyDoc_STRVAR(step_doc,
"Stepper().step(arr, dt, n, kp_xy, kp_z, bz2, kp_yaw, tau_vel_xy, tau_vel_z, drag, acc_up, acc_dn,\n"
"     landed_alt, landed_speed, idle, tau_att)\n\n"
"Advance every vehicle of the MultirotorArray ``arr`` by ``n`` steps of ``dt`` s, in place:\n"
"MultirotorArray._step_scalar's equations (the parameters are MultirotorParams' fields of the\n"
"same names; bz2 is twice the vertical braking deceleration, m/s^2; idle the battery's idle fraction).");

static PyObject *step(Stepper *st, PyObject *args) {
    PyObject *obj;
    double dt, kpxy, kpz, bz2, kpyaw, tau_xy, tau_z, drag, acc_up, acc_dn, l_alt, l_spd, idle, tau_att;
    int n;
    if (!PyArg_ParseTuple(args, "Odiddddddddddddd:step", &obj, &dt, &n, &kpxy, &kpz, &bz2, &kpyaw, &tau_xy, &tau_z,
                          &drag, &acc_up, &acc_dn, &l_alt, &l_spd, &idle, &tau_att))
        return NULL;
    if (n < 1) Py_RETURN_NONE;
    PyObject *nobj = PyObject_GetAttr(obj, name_n);
    if (nobj == NULL) return NULL;
    Py_ssize_t nv = PyLong_AsSsize_t(nobj);
    Py_DECREF(nobj);
    if (nv < 1) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "MultirotorArray.n must be >= 1");
        return NULL;
    }
    if (stepper_views(st, obj, nv) < 0) return NULL;
#define D(k) ((double *)st->views[k].buf)
#define B(k) ((char *)st->views[k].buf)
    double *P = D(F_POS), *V = D(F_VEL), *A = D(F_ACC), *PSP = D(F_POS_SP), *VFF = D(F_VEL_FF), *W = D(F_WIND);
    char *armed_l = B(F_ARMED), *landed_o = B(F_LANDED);
    double *gz_l = D(F_GROUND_Z), *vxy_l = D(F_VXY_MAX), *vup_l = D(F_VZ_UP), *vdn_l = D(F_VZ_DN);
    double *acc_l = D(F_ACC_HOR), *tilt_l = D(F_TILT_ACC), *yrm_l = D(F_YAW_RATE_MAX);
    double *ysp_l = D(F_YAW_SP), *yrsp_l = D(F_YAW_RATE_SP), *yaw_l = D(F_YAW), *rate_o = D(F_YAW_RATE);
    double *roll_l = D(F_ROLL), *pitch_l = D(F_PITCH), *rr_o = D(F_ROLL_RATE), *pr_o = D(F_PITCH_RATE);
    double *bat_l = D(F_BATTERY), *end_l = D(F_ENDURANCE_S);
#undef D
#undef B
    const double itxy = 1.0 / tau_xy, itz = 1.0 / tau_z;
    const double klag = PYMIN(1.0, dt / tau_att);
    const double pi = M_PI;

    for (Py_ssize_t i = 0; i < nv; i++) {
        double p0 = P[3 * i], p1 = P[3 * i + 1], p2 = P[3 * i + 2];
        double v0_ = V[3 * i], v1_ = V[3 * i + 1], v2_ = V[3 * i + 2];
        double x0 = A[3 * i], x1 = A[3 * i + 1], x2 = A[3 * i + 2];
        const double s0 = PSP[3 * i], s1 = PSP[3 * i + 1], s2 = PSP[3 * i + 2];
        const double f0 = VFF[3 * i], f1 = VFF[3 * i + 1], f2 = VFF[3 * i + 2];
        const double w0 = W[3 * i], w1 = W[3 * i + 1], w2 = W[3 * i + 2];
        const int armed = armed_l[i] != 0;
        const double gz = gz_l[i];
        const double vxy = vxy_l[i], vup = vup_l[i], vdn = vdn_l[i], acch = acc_l[i], tilt = tilt_l[i], yrm = yrm_l[i];
        const double ysp = ysp_l[i], yrsp = yrsp_l[i];
        double yaw = yaw_l[i], roll = roll_l[i], pitch = pitch_l[i], bat = bat_l[i];
        const double drain = armed ? dt / end_l[i] : 0.0;
        int landed = 0;
        double rate = 0.0, roll_rate = 0.0, pitch_rate = 0.0;
        if (!armed && p2 >= gz && !(v0_ != 0.0 || v1_ != 0.0 || v2_ != 0.0 || x0 != 0.0 || x1 != 0.0 || x2 != 0.0
                                     || roll != 0.0 || pitch != 0.0)) {
            landed_o[i] = 1;  /* motors off, resting on the ground: nothing changes */
            rate_o[i] = rr_o[i] = pr_o[i] = 0.0;
            continue;
        }
        for (int step_no = 0; step_no < n; step_no++) {
            double e0 = s0 != s0 ? 0.0 : s0 - p0;
            double e1 = s1 != s1 ? 0.0 : s1 - p1;
            double e2 = s2 != s2 ? 0.0 : s2 - p2;
            double gxy = PYMIN(sqrt(acch / PYMAX(hypot(e0, e1), 1e-9)), kpxy);
            double gzz = PYMIN(sqrt(bz2 / PYMAX(fabs(e2), 1e-9)), kpz);
            double c0 = e0 * gxy + f0, c1 = e1 * gxy + f1, c2 = e2 * gzz + f2;
            double s = PYMIN(vxy / PYMAX(hypot(c0, c1), 1e-9), 1.0);
            c0 *= s;
            c1 *= s;
            c2 = PYMIN(PYMAX(c2, -vup), vdn);
            double a0 = (c0 - v0_) * itxy, a1 = (c1 - v1_) * itxy, a2 = (c2 - v2_) * itz;
            s = PYMIN(acch / PYMAX(hypot(a0, a1), 1e-9), 1.0);
            a0 *= s;
            a1 *= s;
            a2 = PYMIN(PYMAX(a2, -acc_up), acc_dn);
            const double r0 = v0_ - w0, r1 = v1_ - w1, r2 = v2_ - w2;
            a0 += drag * r0;
            a1 += drag * r1;
            a2 += drag * r2;
            double axy = hypot(a0, a1);
            s = PYMIN(tilt / PYMAX(axy, 1e-9), 1.0);
            a0 *= s;
            a1 *= s;
            axy *= s;
            if (armed) {
                x0 = x0 + (a0 - x0) * klag;
                x1 = x1 + (a1 - x1) * klag;
                x2 = x2 + (a2 - x2) * klag;
            } else {
                x0 = 0.0; x1 = 0.0; x2 = G;
            }
            v0_ += (x0 - drag * r0) * dt;
            v1_ += (x1 - drag * r1) * dt;
            v2_ += (x2 - drag * r2) * dt;
            p0 += v0_ * dt;
            p1 += v1_ * dt;
            p2 += v2_ * dt;
            int contact = 0;
            if (p2 >= gz) {
                p2 = gz;
                v2_ = PYMIN(v2_, 0.0);
                if (x2 >= -1e-3) {
                    v0_ = v1_ = v2_ = x0 = x1 = x2 = 0.0;
                    contact = 1;
                }
            }
            landed = contact || (p2 > gz - l_alt && fabs(v2_) < l_spd && x2 > -0.5);
            /* heading */
            if (ysp == ysp) {
                rate = kpyaw * (py_mod((ysp - yaw) + pi, TWO_PI) - pi);
            } else {
                rate = yrsp;
            }
            rate = PYMIN(PYMAX(rate, -yrm), yrm);
            if (rate != rate || !armed || landed) rate = 0.0;
            yaw = py_mod((yaw + rate * dt) + pi, TWO_PI) - pi;
            /* attitude for telemetry */
            const double c = cos(yaw), sn = sin(yaw);
            const double fwd = c * x0 + sn * x1;
            const double right = c * x1 - sn * x0;
            const double up = PYMAX(G - x2, 0.0);
            const double pt = -atan2(fwd, up);
            const double rl = atan2(right, hypot(fwd, up));
            pitch_rate = (pt - pitch) / dt;
            roll_rate = (rl - roll) / dt;
            pitch = pt;
            roll = rl;
            bat = PYMAX(bat - drain * (landed ? idle : 1.0 + 0.3 / G * axy), 0.0);
        }
        P[3 * i] = p0; P[3 * i + 1] = p1; P[3 * i + 2] = p2;
        V[3 * i] = v0_; V[3 * i + 1] = v1_; V[3 * i + 2] = v2_;
        A[3 * i] = x0; A[3 * i + 1] = x1; A[3 * i + 2] = x2;
        yaw_l[i] = yaw; roll_l[i] = roll; pitch_l[i] = pitch; bat_l[i] = bat;
        landed_o[i] = (char)landed;
        rate_o[i] = rate;
        rr_o[i] = roll_rate;
        pr_o[i] = pitch_rate;
    }
    Py_RETURN_NONE;
}

/* The kept view of field k of `obj` (exported again, with every other, when the attribute now
 * holds another array), and vehicle i checked against it. 0 ok, -1 error. */
static int field_ready(Stepper *st, PyObject *obj, int k, Py_ssize_t i) {
    PyObject *arr = PyObject_GetAttr(obj, field_names[k]);
    if (arr == NULL) return -1;
    int same = arr == st->objs[k] && st->n > 0;
    Py_DECREF(arr);
    if (!same) {
        PyObject *nobj = PyObject_GetAttr(obj, name_n);
        if (nobj == NULL) return -1;
        Py_ssize_t nv = PyLong_AsSsize_t(nobj);
        Py_DECREF(nobj);
        if (nv < 1) {
            if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "MultirotorArray.n must be >= 1");
            return -1;
        }
        if (stepper_views(st, obj, nv) < 0) return -1;
    }
    if (i < 0 || i >= st->n) {
        PyErr_Format(PyExc_IndexError, "vehicle %zd of %zd", i, st->n);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(get_doc,
"Stepper().get(arr, k, i) -> float | bool | (float, float, float)\n\n"
"Vehicle i's value of field k (FIELDS[k]) of the MultirotorArray ``arr``: what float(arr.<field>[i]),\n"
"bool(...) or tuple(arr.<field>[i].tolist()) give, without numpy's indexing.");

static PyObject *get(Stepper *st, PyObject *args) {
    PyObject *obj;
    int k;
    Py_ssize_t i;
    if (!PyArg_ParseTuple(args, "Oin:get", &obj, &k, &i)) return NULL;
    if (k < 0 || k >= N_FIELDS) return PyErr_Format(PyExc_IndexError, "field %d of %d", k, N_FIELDS);
    if (field_ready(st, obj, k, i) < 0) return NULL;
    switch (FIELDS[k].kind) {
    case 'v': {
        const double *v = (const double *)st->views[k].buf + 3 * i;
        return Py_BuildValue("(ddd)", v[0], v[1], v[2]);
    }
    case 'b':
        return PyBool_FromLong(((const char *)st->views[k].buf)[i] != 0);
    default:
        return PyFloat_FromDouble(((const double *)st->views[k].buf)[i]);
    }
}

PyDoc_STRVAR(set_targets_doc,
"Stepper().set_targets(arr, i, px, py, pz, vx, vy, vz, yaw, yaw_rate)\n\n"
"Vehicle i's position setpoint (m, NED; NaN: that axis free), velocity feed-forward (m/s), yaw\n"
"setpoint and yaw-rate setpoint (rad, rad/s; NaN: none) written into ``arr``'s pos_sp, vel_ff,\n"
"yaw_sp and yaw_rate_sp, as the four numpy assignments of Vehicle._targets write them.");

static PyObject *set_targets(Stepper *st, PyObject *args) {
    PyObject *obj;
    Py_ssize_t i;
    double px, py, pz, vx, vy, vz, yaw, yaw_rate;
    if (!PyArg_ParseTuple(args, "Ondddddddd:set_targets", &obj, &i, &px, &py, &pz, &vx, &vy, &vz, &yaw, &yaw_rate))
        return NULL;
    if (field_ready(st, obj, F_POS_SP, i) < 0 || field_ready(st, obj, F_VEL_FF, i) < 0 ||
        field_ready(st, obj, F_YAW_SP, i) < 0 || field_ready(st, obj, F_YAW_RATE_SP, i) < 0)
        return NULL;
    double *p = (double *)st->views[F_POS_SP].buf + 3 * i, *v = (double *)st->views[F_VEL_FF].buf + 3 * i;
    p[0] = px; p[1] = py; p[2] = pz;
    v[0] = vx; v[1] = vy; v[2] = vz;
    ((double *)st->views[F_YAW_SP].buf)[i] = yaw;
    ((double *)st->views[F_YAW_RATE_SP].buf)[i] = yaw_rate;
    Py_RETURN_NONE;
}

static PyMethodDef stepper_methods[] = {
    {"step", (PyCFunction)step, METH_VARARGS, step_doc},
    {"get", (PyCFunction)get, METH_VARARGS, get_doc},
    {"set_targets", (PyCFunction)set_targets, METH_VARARGS, set_targets_doc},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject StepperType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "uav_stack.fcu._dynamics.Stepper",
    .tp_doc = PyDoc_STR("Steps one MultirotorArray (keep one per array: it keeps views of its arrays)."),
    .tp_basicsize = sizeof(Stepper),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_dealloc = (destructor)stepper_dealloc,
    .tp_methods = stepper_methods,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_dynamics",
    "The virtual FCU's multirotor step, compiled (see dynamics.MultirotorArray.step).", -1, NULL,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__dynamics(void) {
    for (int k = 0; k < N_FIELDS; k++) {
        field_names[k] = PyUnicode_InternFromString(FIELDS[k].name);
        if (field_names[k] == NULL) return NULL;
    }
    name_n = PyUnicode_InternFromString("n");
    if (name_n == NULL) return NULL;
    if (PyType_Ready(&StepperType) < 0) return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    PyObject *names = PyTuple_New(N_FIELDS);
    if (names == NULL) {
        Py_DECREF(m);
        return NULL;
    }
    for (int k = 0; k < N_FIELDS; k++) PyTuple_SET_ITEM(names, k, Py_NewRef(field_names[k]));
    if (PyModule_AddObject(m, "FIELDS", names) < 0) {  /* the field index of get(): Stepper's order */
        Py_DECREF(names);
        Py_DECREF(m);
        return NULL;
    }
    Py_INCREF(&StepperType);
    if (PyModule_AddObject(m, "Stepper", (PyObject *)&StepperType) < 0) {
        Py_DECREF(&StepperType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
