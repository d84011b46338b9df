/* The virtual FCU's GLOBAL_POSITION_INT, from the physics state to the MAVLink 2 frame, compiled
 * (uav_stack/fcu/telemetry.py: global_position_int, then uav_stack.mavcodec.pack).
 *
 * Why: a virtual UAV's FCU sends GLOBAL_POSITION_INT on every tick, and a tick's Python runs
 * with caches emptied since the last one: the encoder cost 131 us of thread CPU per call
 * 100 ms apart against 4.8 us back to back (benchmarks/tick_cost.py), and the frame's packing and
 * queueing as much again. Here the same arithmetic runs in one small routine.
 *
 * The same result as the Python path, bit for bit (tests/test_fcu_telemetry_frame.py compares
 * frames over random states): the WGS84 conversion of uav_stack/geo.py with its operations in
 * the same order (built with -ffp-contract=off, no fused multiply-add), Python's semantics where
 * C's differ (** is pow, % on floats takes the divisor's sign, round() rounds half to even: rint
 * in the default rounding mode), and math.hypot called as Python's own (its algorithm is not
 * libm's). The frame is pymavlink's: MAVLink 2, trailing zero bytes of the payload cut, X.25 CRC
 * with the message's CRC extra. Signing links are left to the Python path (telemetry.py).
 *
 * Built at install when a C compiler and Python's headers are there (setup.py, optional).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>
#include "_pyfloat.h"
#include "../_x25crc.h"

#define MSG_ID 33        /* GLOBAL_POSITION_INT */
#define CRC_EXTRA 104
#define PAYLOAD_LEN 28   /* <IiiiihhhH */
#define HEADER_LEN 10

static PyObject *py_hypot;  /* math.hypot */
/* WGS84 and friends, as uav_stack.geo computes them (set once by configure()) */
static double A, B, F, E2, EP2, RAD80;
static int configured;

static const double RAD_TO_DEG = 180.0 / 3.141592653589793;  /* CPython's math.degrees factor */

/* telemetry._i32 / _i16: rounded half to even, held in range, non-finite -> 0 */
static int32_t i32(double x) {
    if (-2147483647.0 <= x && x <= 2147483647.0) return (int32_t)rint(x);
    return isfinite(x) ? (x > 0.0 ? 2147483647 : -2147483647) : 0;
}

static int16_t i16(double x) {
    if (-32767.0 <= x && x <= 32767.0) return (int16_t)rint(x);
    return isfinite(x) ? (x > 0.0 ? 32767 : -32767) : 0;
}

/* telemetry._cdeg_heading */
static uint16_t cdeg_heading(double yaw) {
    if (!isfinite(yaw)) return 65535;
    double c = rint(py_mod(yaw * RAD_TO_DEG, 360.0) * 100.0);
    return (uint16_t)((int64_t)c % 36000);
}

static int hypot_py(double x, double y, double *out) {
    PyObject *args[2] = {PyFloat_FromDouble(x), PyFloat_FromDouble(y)};
    PyObject *r = NULL;
    if (args[0] != NULL && args[1] != NULL) r = PyObject_Vectorcall(py_hypot, args, 2, NULL);
    Py_XDECREF(args[0]);
    Py_XDECREF(args[1]);
    if (r == NULL) return -1;
    *out = PyFloat_AsDouble(r);
    Py_DECREF(r);
    return 0;
}

/* geo.ecef_to_geodetic: Bowring's method, two refinements; degrees, degrees, metres */
static int ecef_to_geodetic(double x, double y, double z, double *lat_deg, double *lon_deg, double *alt) {
    double lon = atan2(y, x), p;
    if (hypot_py(x, y, &p) < 0) return -1;
    if (p < 1e-9) {
        double lat = copysign(3.141592653589793 / 2, z);
        *lat_deg = lat * RAD_TO_DEG;
        *lon_deg = lon * RAD_TO_DEG;
        *alt = fabs(z) - B;
        return 0;
    }
    double theta = atan2(z * A, p * B), lat = 0.0;
    for (int k = 0; k < 2; k++) {
        double st = sin(theta), ct = cos(theta);
        lat = atan2(z + EP2 * B * pow(st, 3.0), p - E2 * A * pow(ct, 3.0));
        theta = atan2((1.0 - F) * sin(lat), cos(lat));
    }
    double s = sin(lat);
    double n = A / sqrt(1.0 - E2 * s * s);
    *alt = fabs(lat) < RAD80 ? p / cos(lat) - n : z / s - n * (1.0 - E2);
    *lat_deg = lat * RAD_TO_DEG;
    *lon_deg = lon * RAD_TO_DEG;
    return 0;
}

/* Element i of a C-contiguous float64 array of `per` values per vehicle. */
static int read_row(PyObject *arr, Py_ssize_t i, int per, double *out) {
    Py_buffer v;
    if (PyObject_GetBuffer(arr, &v, PyBUF_FORMAT | PyBUF_C_CONTIGUOUS) < 0) return -1;
    int ok = v.format != NULL && strcmp(v.format, "d") == 0 && (i + 1) * per * (Py_ssize_t)sizeof(double) <= v.len && i >= 0;
    if (ok) memcpy(out, (const char *)v.buf + i * per * sizeof(double), per * sizeof(double));
    PyBuffer_Release(&v);
    if (!ok) PyErr_SetString(PyExc_ValueError, "a C-contiguous float64 array with the vehicle's row was expected");
    return ok ? 0 : -1;
}

static void put_u32(unsigned char *p, uint32_t v) { p[0] = v; p[1] = v >> 8; p[2] = v >> 16; p[3] = v >> 24; }
static void put_u16(unsigned char *p, uint16_t v) { p[0] = v; p[1] = v >> 8; }

PyDoc_STRVAR(configure_doc,
"configure(hypot, a, b, f, e2, ep2, rad80)\n\n"
"Python's math.hypot and uav_stack.geo's WGS84 constants (m; radians(80)), set once at import.");

static PyObject *configure(PyObject *self, PyObject *args) {
    PyObject *h;
    if (!PyArg_ParseTuple(args, "Odddddd:configure", &h, &A, &B, &F, &E2, &EP2, &RAD80)) return NULL;
    if (!PyCallable_Check(h)) return PyErr_Format(PyExc_TypeError, "hypot must be callable");
    Py_INCREF(h);
    Py_XSETREF(py_hypot, h);
    configured = 1;
    Py_RETURN_NONE;
}

PyDoc_STRVAR(gpi_doc,
"global_position_int(pos, vel, yaw, i, frame, error, home_alt, sim_time, seq, sysid, compid) -> bytes\n\n"
"The MAVLink 2 frame of vehicle i's GLOBAL_POSITION_INT, as telemetry.global_position_int and\n"
"mavcodec.pack make it: pos, vel (n, 3) and yaw (n,) are the MultirotorArray's float64 arrays\n"
"(local NED at the frame's origin, m, m/s, rad); frame is LocalFrame.constants; error the\n"
"position error added to what is reported (NED, m); home_alt m AMSL; sim_time s since boot.");

static PyObject *global_position_int(PyObject *self, PyObject *args) {
    PyObject *pos, *vel, *yaw;
    Py_ssize_t i;
    double sl, cl, so, co, x0, y0, z0, de_n, de_e, de_d, home_alt, sim_time;
    int seq, sysid, compid;
    if (!PyArg_ParseTuple(args, "OOOn(ddddddd)(ddd)ddiii:global_position_int", &pos, &vel, &yaw, &i,
                          &sl, &cl, &so, &co, &x0, &y0, &z0, &de_n, &de_e, &de_d, &home_alt, &sim_time,
                          &seq, &sysid, &compid))
        return NULL;
    if (!configured) return PyErr_Format(PyExc_RuntimeError, "_telemetry.configure() first");
    double p[3], v[3], y;
    if (read_row(pos, i, 3, p) < 0 || read_row(vel, i, 3, v) < 0 || read_row(yaw, i, 1, &y) < 0) return NULL;
    /* Vehicle.reported_geodetic: geodetic() when there is no error, else with it */
    double e, n, u;
    if (de_n == 0.0 && de_e == 0.0 && de_d == 0.0) {
        e = p[1]; n = p[0]; u = -p[2];
    } else {
        e = p[1] + de_e; n = p[0] + de_n; u = -(p[2] + de_d);
    }
    /* LocalFrame.to_geodetic */
    double dx = -so * e - sl * co * n + cl * co * u;
    double dy = co * e - sl * so * n + cl * so * u;
    double dz = cl * n + sl * u;
    double lat, lon, alt;
    if (ecef_to_geodetic(x0 + dx, y0 + dy, z0 + dz, &lat, &lon, &alt) < 0) return NULL;
    double ms = sim_time * 1000.0;
    if (!isfinite(ms) || ms < 0.0 || ms >= 9.2e18)
        return PyErr_Format(PyExc_ValueError, "sim_time %g s cannot be a boot time", sim_time);

    unsigned char f[HEADER_LEN + PAYLOAD_LEN + 2];
    unsigned char *q = f + HEADER_LEN;
    put_u32(q, (uint32_t)((uint64_t)ms & 0xFFFFFFFFu));
    put_u32(q + 4, (uint32_t)i32(lat * 1e7));
    put_u32(q + 8, (uint32_t)i32(lon * 1e7));
    put_u32(q + 12, (uint32_t)i32(alt * 1000.0));
    put_u32(q + 16, (uint32_t)i32((alt - home_alt) * 1000.0));
    put_u16(q + 20, (uint16_t)i16(v[0] * 100.0));
    put_u16(q + 22, (uint16_t)i16(v[1] * 100.0));
    put_u16(q + 24, (uint16_t)i16(v[2] * 100.0));
    put_u16(q + 26, cdeg_heading(y));
    Py_ssize_t plen = PAYLOAD_LEN;
    while (plen > 1 && q[plen - 1] == 0) plen--;  /* MAVLink 2: trailing zeros cut, as pymavlink does */
    f[0] = 0xFD;
    f[1] = (unsigned char)plen;
    f[2] = 0;  /* incompat flags: unsigned */
    f[3] = 0;
    f[4] = (unsigned char)(seq & 0xFF);
    f[5] = (unsigned char)(sysid & 0xFF);
    f[6] = (unsigned char)(compid & 0xFF);
    f[7] = MSG_ID & 0xFF;
    f[8] = (MSG_ID >> 8) & 0xFF;
    f[9] = (MSG_ID >> 16) & 0xFF;
    unsigned char extra = CRC_EXTRA;
    uint16_t crc = crc_accumulate(crc_accumulate(0xFFFF, f + 1, HEADER_LEN - 1 + plen), &extra, 1);
    put_u16(f + HEADER_LEN + plen, crc);
    return PyBytes_FromStringAndSize((const char *)f, HEADER_LEN + plen + 2);
}

static PyMethodDef methods[] = {
    {"configure", configure, METH_VARARGS, configure_doc},
    {"global_position_int", global_position_int, METH_VARARGS, gpi_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_telemetry",
    "The virtual FCU's GLOBAL_POSITION_INT frame, compiled (see uav_stack/fcu/telemetry.py).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__telemetry(void) { return PyModule_Create(&module); }
