/*
 * swarmnet._intake: an edge-feed batch, or a direct pose, into the neighbour table in one compiled pass.
 *
 * Why: a UAV of 50 on the edge feed takes in about 500 poses a second, four or five batches
 * per tick. In Python each pose is a msgpack decode, a range check, a Pose object, the
 * neighbour table's sequence rules and an age: about a quarter of the UAV's main thread
 * (docs/benchmarks.md). This module does the same for a *clean* batch, one that every rule
 * accepts, and says "not clean" (None) for anything else, without touching the table: the
 * caller then runs the Python path (swarmnet.messages, swarmnet.neighbours), which names the
 * reason and counts it. So the rules stay written once, in Python; this is their fast path,
 * narrower than they are, never wider (tests/test_intake.py checks both on random batches).
 *
 * The wire format (swarmnet/messages.py): a batch is the msgpack array
 * [tag, seq, t_wall_us, [sender, ...], [pose payload (bin), ...]], and each pose payload the
 * array [tag, uav, realm, seq, t_sim_ms, t_wall_us, x_cm, y_cm, z_cm, vx_cm_s, vy_cm_s,
 * vz_cm_s, yaw_1e-4_rad] of integers. The table's rules are NeighbourTable.update's.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#define MAX_POSE_BYTES 48
#define MAX_BATCH_POSES 4096
#define MAX_BATCH_BYTES (16 + MAX_BATCH_POSES * (MAX_POSE_BYTES + 2) + 16)
#define UAV_ID_MIN 1
#define UAV_ID_MAX 65535
#define INT16 32767
#define INT32 2147483647LL
#define UINT32 4294967295LL
#define SEQ_MOD 65536
#define SEQ_HALF 32768
#define RATE_ALPHA 0.2 /* NeighbourTable: EWMA weight of the newest interval */

/* ---- msgpack, the few forms a batch uses ------------------------------------------------ */

typedef struct {
    const unsigned char *p, *end;
} Reader;

static inline uint64_t be(const unsigned char *p, int n) {
    uint64_t v = 0;
    for (int i = 0; i < n; i++) v = (v << 8) | p[i];
    return v;
}

/* An integer in any of msgpack's forms, as int64 (a uint64 above INT64_MAX: not clean). 0 ok, -1 not. */
static int read_int(Reader *r, int64_t *out) {
    if (r->p >= r->end) return -1;
    unsigned char c = *r->p++;
    if (c <= 0x7f) { *out = c; return 0; }
    if (c >= 0xe0) { *out = (int8_t)c; return 0; }
    static const int size[] = {1, 2, 4, 8};
    int n;
    int is_signed;
    if (c >= 0xcc && c <= 0xcf) { n = size[c - 0xcc]; is_signed = 0; }
    else if (c >= 0xd0 && c <= 0xd3) { n = size[c - 0xd0]; is_signed = 1; }
    else return -1;
    if (r->end - r->p < n) return -1;
    uint64_t v = be(r->p, n);
    r->p += n;
    if (is_signed) {
        int shift = 64 - 8 * n;
        *out = shift ? ((int64_t)(v << shift)) >> shift : (int64_t)v;
    } else {
        if (v > (uint64_t)INT64_MAX) return -1;
        *out = (int64_t)v;
    }
    return 0;
}

static int read_int_in(Reader *r, int64_t lo, int64_t hi, int64_t *out) {
    return (read_int(r, out) == 0 && *out >= lo && *out <= hi) ? 0 : -1;
}

/* An array header (fixarray, array16, array32): its length, or -1. */
static Py_ssize_t read_array(Reader *r) {
    if (r->p >= r->end) return -1;
    unsigned char c = *r->p++;
    if (c >= 0x90 && c <= 0x9f) return c & 0x0f;
    int n = c == 0xdc ? 2 : c == 0xdd ? 4 : 0;
    if (!n || r->end - r->p < n) return -1;
    uint64_t v = be(r->p, n);
    r->p += n;
    return (Py_ssize_t)v;
}

/* ---- one pose ------------------------------------------------------------------------- */

typedef struct {
    int64_t uav, realm, seq, t_sim_ms, t_wall_us, x, y, z, vx, vy, vz, yaw;
} WirePose;

/* The pose in [p, p + n): 0 if every rule of decode_pose accepts it, -1 otherwise. */
static int read_pose(const unsigned char *p, Py_ssize_t n, int64_t pose_tag, WirePose *w) {
    Reader r = {p, p + n};
    int64_t t;
    if (n > MAX_POSE_BYTES || n < 1 || *r.p++ != 0x9d) return -1; /* fixarray of 13 */
    if (read_int(&r, &t) || t != pose_tag) return -1;
    if (read_int_in(&r, UAV_ID_MIN, UAV_ID_MAX, &w->uav)) return -1;
    if (read_int_in(&r, 0, 1, &w->realm)) return -1;
    if (read_int_in(&r, 0, 0xFFFF, &w->seq)) return -1;
    if (read_int_in(&r, 0, UINT32, &w->t_sim_ms)) return -1;
    if (read_int_in(&r, 0, INT64_MAX, &w->t_wall_us)) return -1;
    if (read_int_in(&r, -INT32, INT32, &w->x)) return -1;
    if (read_int_in(&r, -INT32, INT32, &w->y)) return -1;
    if (read_int_in(&r, -INT16, INT16, &w->z)) return -1;
    if (read_int_in(&r, -INT16, INT16, &w->vx)) return -1;
    if (read_int_in(&r, -INT16, INT16, &w->vy)) return -1;
    if (read_int_in(&r, -INT16, INT16, &w->vz)) return -1;
    if (read_int_in(&r, -31416, 31416, &w->yaw)) return -1;
    return r.p == r.end ? 0 : -1; /* nothing after the 13 fields */
}

/* ---- one batch: its envelope and poses, checked before anything is applied ---------------- */

typedef struct {
    Py_ssize_t n, capacity;
    WirePose *poses;
} Batch;

/* Room for n poses in *b (it only grows); 0 ok, -1 out of memory (a MemoryError set). */
static int reserve(Batch *b, Py_ssize_t n) {
    if (n <= b->capacity) return 0;
    WirePose *p = PyMem_Realloc(b->poses, (size_t)n * sizeof(WirePose));
    if (p == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    b->poses = p;
    b->capacity = n;
    return 0;
}

/* Whether a batch is clean: 1 yes, 0 no, -1 out of memory. The senders and the poses are read
 * side by side. With `b`, the batch is kept there (take()); without, only `*others` is (count(),
 * on the pose inlet's thread, perhaps while the owner's take() has its batch in the scratch
 * space): how many poses are not `exclude`'s. */
static int read_batch(const unsigned char *data, Py_ssize_t len, int64_t batch_tag, int64_t pose_tag, Batch *b,
                      int64_t exclude, long long *others) {
    Reader r = {data, data + len};
    int64_t t;
    if (len < 1 || len > MAX_BATCH_BYTES) return 0;
    if (*r.p++ != 0x95) return 0; /* fixarray of 5 */
    if (read_int(&r, &t) || t != batch_tag) return 0;
    if (read_int_in(&r, 0, UINT32, &t)) return 0;    /* seq */
    if (read_int_in(&r, 0, INT64_MAX, &t)) return 0; /* t_wall, us */
    Py_ssize_t n = read_array(&r);
    if (n < 0 || n > MAX_BATCH_POSES) return 0;
    if (b != NULL && reserve(b, n) < 0) return -1;
    Reader senders = r;
    for (Py_ssize_t i = 0; i < n; i++)
        if (read_int_in(&r, UAV_ID_MIN, UAV_ID_MAX, &t)) return 0;
    if (read_array(&r) != n) return 0;
    long long not_excluded = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        int64_t sender;
        WirePose one, *w = b != NULL ? &b->poses[i] : &one;
        read_int(&senders, &sender); /* read (and checked) above */
        if (r.end - r.p < 2 || *r.p != 0xc4) return 0; /* bin 8 */
        Py_ssize_t plen = r.p[1];
        r.p += 2;
        if (r.end - r.p < plen || read_pose(r.p, plen, pose_tag, w) || w->uav != sender) return 0;
        r.p += plen;
        not_excluded += sender != exclude;
    }
    if (r.p != r.end) return 0;
    if (b != NULL) b->n = n;
    if (others != NULL) *others = not_excluded;
    return 1;
}

/* ---- the Intake object ---------------------------------------------------------------- */

enum { P_UAV, P_REALM, P_SEQ, P_T_SIM, P_T_WALL, P_X, P_Y, P_Z, P_VX, P_VY, P_VZ, P_YAW, N_POSE };
static const char *POSE_FIELDS[N_POSE] = {"uav", "realm", "seq", "t_sim", "t_wall", "x", "y", "z", "vx", "vy", "vz", "yaw"};
enum { N_POSE_, N_LAST_RECV, N_USED, N_RECEIVED, N_LOST, N_DUPLICATES, N_OUT_OF_ORDER, N_INTERVAL, N_NEIGHBOUR };
static const char *NEIGHBOUR_FIELDS[N_NEIGHBOUR] = {"pose", "last_recv", "used", "received", "lost", "duplicates",
                                                    "out_of_order", "interval"};

typedef struct {
    PyObject_HEAD
    PyTypeObject *pose_type;
    PyTypeObject *neighbour_type;
    PyObject *realms; /* tuple: the Realm of wire value 0 and 1 */
    int64_t batch_tag, pose_tag;
    PyObject *pose_descr[N_POSE];           /* the slots' member descriptors */
    PyObject *neighbour_name[N_NEIGHBOUR];  /* interned attribute names */
    PyObject *neighbour_descr[N_NEIGHBOUR];
    Batch batch;                            /* scratch: the batch being taken (owner's thread only) */
} Intake;

static void Intake_dealloc(Intake *self) {
    Py_XDECREF(self->pose_type);
    Py_XDECREF(self->neighbour_type);
    Py_XDECREF(self->realms);
    for (int i = 0; i < N_POSE; i++) Py_XDECREF(self->pose_descr[i]);
    for (int i = 0; i < N_NEIGHBOUR; i++) {
        Py_XDECREF(self->neighbour_name[i]);
        Py_XDECREF(self->neighbour_descr[i]);
    }
    PyMem_Free(self->batch.poses);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* A data descriptor of `type` for slot `name` (a dataclass with slots=True has one per field). */
static PyObject *slot_descriptor(PyTypeObject *type, const char *name) {
    PyObject *d = PyObject_GetAttrString((PyObject *)type, name);
    if (d == NULL) return NULL;
    if (Py_TYPE(d)->tp_descr_get == NULL || Py_TYPE(d)->tp_descr_set == NULL) {
        PyErr_Format(PyExc_TypeError, "%s.%s is not a slot", type->tp_name, name);
        Py_DECREF(d);
        return NULL;
    }
    return d;
}

static int Intake_init(Intake *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"pose_type", "neighbour_type", "realms", "batch_tag", "pose_tag", NULL};
    PyObject *pose_type, *neighbour_type, *realms;
    long long batch_tag, pose_tag;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "O!O!O!LL", kwlist, &PyType_Type, &pose_type, &PyType_Type,
                                     &neighbour_type, &PyTuple_Type, &realms, &batch_tag, &pose_tag))
        return -1;
    if (PyTuple_GET_SIZE(realms) != 2) {
        PyErr_SetString(PyExc_ValueError, "realms: the Realm of wire values 0 and 1");
        return -1;
    }
    Py_INCREF(pose_type);
    Py_INCREF(neighbour_type);
    Py_INCREF(realms);
    self->pose_type = (PyTypeObject *)pose_type;
    self->neighbour_type = (PyTypeObject *)neighbour_type;
    self->realms = realms;
    self->batch_tag = batch_tag;
    self->pose_tag = pose_tag;
    for (int i = 0; i < N_POSE; i++)
        if ((self->pose_descr[i] = slot_descriptor(self->pose_type, POSE_FIELDS[i])) == NULL) return -1;
    for (int i = 0; i < N_NEIGHBOUR; i++) {
        if ((self->neighbour_name[i] = PyUnicode_InternFromString(NEIGHBOUR_FIELDS[i])) == NULL) return -1;
        if ((self->neighbour_descr[i] = slot_descriptor(self->neighbour_type, NEIGHBOUR_FIELDS[i])) == NULL) return -1;
    }
    return 0;
}

/* A Pose from its wire fields, scaled as decode_pose scales them, without running its __init__. */
static PyObject *make_pose(Intake *self, const WirePose *w) {
    PyTypeObject *type = self->pose_type;
    PyObject *pose = type->tp_alloc(type, 0);
    if (pose == NULL) return NULL;
    PyObject *v[N_POSE];
    v[P_UAV] = PyLong_FromLongLong(w->uav);
    v[P_REALM] = PyTuple_GET_ITEM(self->realms, w->realm);
    Py_INCREF(v[P_REALM]);
    v[P_SEQ] = PyLong_FromLongLong(w->seq);
    v[P_T_SIM] = PyFloat_FromDouble((double)w->t_sim_ms / 1000.0);
    v[P_T_WALL] = PyFloat_FromDouble((double)w->t_wall_us / 1e6);
    v[P_X] = PyFloat_FromDouble((double)w->x / 100.0);
    v[P_Y] = PyFloat_FromDouble((double)w->y / 100.0);
    v[P_Z] = PyFloat_FromDouble((double)w->z / 100.0);
    v[P_VX] = PyFloat_FromDouble((double)w->vx / 100.0);
    v[P_VY] = PyFloat_FromDouble((double)w->vy / 100.0);
    v[P_VZ] = PyFloat_FromDouble((double)w->vz / 100.0);
    v[P_YAW] = PyFloat_FromDouble((double)w->yaw / 1e4);
    int bad = 0;
    for (int i = 0; i < N_POSE; i++) {
        PyObject *d = self->pose_descr[i];
        if (v[i] == NULL || Py_TYPE(d)->tp_descr_set(d, pose, v[i]) < 0) bad = 1;
        Py_XDECREF(v[i]);
    }
    if (bad) {
        if (!PyErr_Occurred()) PyErr_NoMemory();
        Py_DECREF(pose);
        return NULL;
    }
    return pose;
}

/* The neighbour's attribute i: through its slot when it is a Neighbour, by name otherwise. */
static PyObject *nget(Intake *self, PyObject *n, int i) {
    if (Py_TYPE(n) == self->neighbour_type) {
        PyObject *d = self->neighbour_descr[i];
        return Py_TYPE(d)->tp_descr_get(d, n, (PyObject *)self->neighbour_type);
    }
    return PyObject_GetAttr(n, self->neighbour_name[i]);
}

static int nset(Intake *self, PyObject *n, int i, PyObject *v) {
    if (v == NULL) return -1;
    int rc;
    if (Py_TYPE(n) == self->neighbour_type) {
        PyObject *d = self->neighbour_descr[i];
        rc = Py_TYPE(d)->tp_descr_set(d, n, v);
    } else {
        rc = PyObject_SetAttr(n, self->neighbour_name[i], v);
    }
    Py_DECREF(v);
    return rc;
}

static int nget_double(Intake *self, PyObject *n, int i, double *out) {
    PyObject *v = nget(self, n, i);
    if (v == NULL) return -1;
    *out = PyFloat_AsDouble(v);
    Py_DECREF(v);
    return (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

static int nadd(Intake *self, PyObject *n, int i, long long k) {
    PyObject *v = nget(self, n, i);
    if (v == NULL) return -1;
    long long x = PyLong_AsLongLong(v);
    Py_DECREF(v);
    if (x == -1 && PyErr_Occurred()) return -1;
    return nset(self, n, i, PyLong_FromLongLong(x + k));
}

/* The stamp (s) and sequence number of a pose in the table: through its slots when it is a Pose. */
static int pose_stamp_seq(Intake *self, PyObject *pose, double *t_wall, long long *seq) {
    PyObject *t, *s;
    if (Py_TYPE(pose) == self->pose_type) {
        PyObject *dt = self->pose_descr[P_T_WALL], *ds = self->pose_descr[P_SEQ];
        t = Py_TYPE(dt)->tp_descr_get(dt, pose, (PyObject *)self->pose_type);
        s = t ? Py_TYPE(ds)->tp_descr_get(ds, pose, (PyObject *)self->pose_type) : NULL;
    } else {
        t = PyObject_GetAttrString(pose, "t_wall");
        s = t ? PyObject_GetAttrString(pose, "seq") : NULL;
    }
    int rc = -1;
    if (t != NULL && s != NULL) {
        *t_wall = PyFloat_AsDouble(t);
        *seq = PyLong_AsLongLong(s);
        rc = ((*t_wall == -1.0 || *seq == -1) && PyErr_Occurred()) ? -1 : 0;
    }
    Py_XDECREF(t);
    Py_XDECREF(s);
    return rc;
}

/* Its id and transport age (s) appended to `srcs` and `ages`: a pose the table took. 0 ok, -1 error. */
static int note_taken(const WirePose *w, double at, PyObject *srcs, PyObject *ages) {
    PyObject *u = PyLong_FromLongLong(w->uav);
    PyObject *age = PyFloat_FromDouble(at - (double)w->t_wall_us / 1e6);
    int bad = u == NULL || age == NULL || PyList_Append(srcs, u) < 0 || PyList_Append(ages, age) < 0;
    Py_XDECREF(u);
    Py_XDECREF(age);
    return bad ? -1 : 0;
}

/* NeighbourTable.update for one clean pose arrived at `at`, and note_taken() if the table takes
 * it: 1 taken, 0 not (duplicate or older), -1 error. The Pose is made only when it is taken. */
static int update(Intake *self, PyObject *table, const WirePose *w, double at, PyObject *srcs, PyObject *ages) {
    PyObject *key = PyLong_FromLongLong(w->uav);
    if (key == NULL) return -1;
    PyObject *n = PyDict_GetItemWithError(table, key); /* borrowed */
    if (n == NULL) {
        if (PyErr_Occurred()) goto fail;
        PyObject *pose = make_pose(self, w);
        if (pose == NULL) goto fail;
        PyObject *a = PyFloat_FromDouble(at);
        PyObject *args = PyTuple_New(0);
        PyObject *kw = (a && args) ? PyDict_New() : NULL;
        PyObject *nb = NULL;
        if (kw && PyDict_SetItemString(kw, "pose", pose) == 0 && PyDict_SetItemString(kw, "first_seen", a) == 0 &&
            PyDict_SetItemString(kw, "last_recv", a) == 0)
            nb = PyObject_Call((PyObject *)self->neighbour_type, args, kw);
        Py_XDECREF(a);
        Py_XDECREF(args);
        Py_XDECREF(kw);
        if (nb == NULL || PyDict_SetItem(table, key, nb) < 0) {
            Py_XDECREF(nb);
            Py_DECREF(pose);
            goto fail;
        }
        Py_DECREF(nb);
        Py_DECREF(key);
        Py_DECREF(pose);
        return note_taken(w, at, srcs, ages) < 0 ? -1 : 1;
    }
    Py_INCREF(n);
    PyObject *old = nget(self, n, N_POSE_);
    if (old == NULL) goto fail_n;
    double old_t_wall;
    long long old_seq;
    int err = pose_stamp_seq(self, old, &old_t_wall, &old_seq);
    Py_DECREF(old);
    if (err) goto fail_n;
    double t_wall = (double)w->t_wall_us / 1e6;
    int64_t diff = ((w->seq - old_seq) % SEQ_MOD + SEQ_MOD) % SEQ_MOD;
    if (diff == 0 && t_wall == old_t_wall) {
        if (nadd(self, n, N_DUPLICATES, 1) < 0) goto fail_n;
        Py_DECREF(n);
        Py_DECREF(key);
        return 0;
    }
    if (diff >= SEQ_HALF || diff == 0) {
        /* behind in sequence space; a restarted sender is told apart by a clearly newer stamp */
        if (t_wall <= old_t_wall + 1.0) {
            if (nadd(self, n, N_OUT_OF_ORDER, 1) < 0) goto fail_n;
            Py_DECREF(n);
            Py_DECREF(key);
            return 0;
        }
        diff = 1;
    }
    if (nadd(self, n, N_LOST, diff - 1) < 0 || nadd(self, n, N_RECEIVED, 1) < 0) goto fail_n;
    double gap = t_wall - old_t_wall;
    if (gap > 0.0) {
        double iv;
        if (nget_double(self, n, N_INTERVAL, &iv) < 0) goto fail_n;
        iv = iv == 0.0 ? gap : iv + RATE_ALPHA * (gap - iv);
        if (nset(self, n, N_INTERVAL, PyFloat_FromDouble(iv)) < 0) goto fail_n;
    }
    /* nset takes each new reference, also when it fails */
    if (nset(self, n, N_POSE_, make_pose(self, w)) < 0 || nset(self, n, N_LAST_RECV, PyFloat_FromDouble(at)) < 0 ||
        nset(self, n, N_USED, Py_NewRef(Py_False)) < 0)
        goto fail_n;
    Py_DECREF(n);
    Py_DECREF(key);
    return note_taken(w, at, srcs, ages) < 0 ? -1 : 1;
fail_n:
    Py_DECREF(n);
fail:
    Py_DECREF(key);
    return -1;
}

PyDoc_STRVAR(take_doc,
"take(data, own, table, at, srcs, ages) -> int | None\n\n"
"An edge-feed batch ``data`` (bytes) that arrived at ``at`` (wall time, s) into ``table`` (the\n"
"NeighbourTable's dict of Neighbour by UAV id), as SwarmNode's Python path would take it: every\n"
"pose but ``own``'s (0: none) applied with NeighbourTable.update's rules; the id and the\n"
"transport age (``at`` - the pose's stamp, s) of each one taken appended to ``srcs`` and\n"
"``ages``. Returns how many poses were not ``own``'s; None, with nothing changed, if any rule\n"
"would refuse anything in the batch: the caller then takes it the Python way, which names why.");

static PyObject *Intake_take(Intake *self, PyObject *args) {
    Py_buffer buf;
    long long own;
    PyObject *table, *srcs, *ages;
    double at;
    if (!PyArg_ParseTuple(args, "y*LO!dO!O!", &buf, &own, &PyDict_Type, &table, &at, &PyList_Type, &srcs, &PyList_Type,
                          &ages))
        return NULL;
    Batch *b = &self->batch;
    long long not_own = 0;
    int clean = read_batch(buf.buf, buf.len, self->batch_tag, self->pose_tag, b, own, &not_own);
    PyBuffer_Release(&buf);
    if (clean < 0) return NULL;
    if (!clean) Py_RETURN_NONE;
    for (Py_ssize_t i = 0; i < b->n; i++)
        if (b->poses[i].uav != own && update(self, table, &b->poses[i], at, srcs, ages) < 0) return NULL;
    return PyLong_FromLongLong(not_own);
}

/* The UAV id of a key "mrs/<swarm>/<uav>/...", as swarmnet.keyspace.uav_from_key reads it, for
 * ASCII digits only (narrower: other Unicode digits are declined); -1 if not one. */
static int64_t uav_of_key(const char *k, Py_ssize_t n) {
    if (n < 4 || memcmp(k, "mrs/", 4) != 0) return -1;
    Py_ssize_t i = 4;
    while (i < n && k[i] != '/') i++; /* the swarm */
    if (i >= n) return -1;
    Py_ssize_t start = ++i, digits = 0;
    int64_t v = 0;
    while (i < n && k[i] != '/') {
        if (k[i] < '0' || k[i] > '9' || ++digits > 5) return -1;
        v = v * 10 + (k[i] - '0');
        i++;
    }
    if (i == start || v < UAV_ID_MIN || v > UAV_ID_MAX) return -1;
    return v;
}

PyDoc_STRVAR(take_pose_doc,
"take_pose(key, data, own, table, at, srcs, ages) -> int | None\n\n"
"A direct pose ``data`` (bytes) that arrived at ``at`` (wall time, s) on ``key``\n"
"(``mrs/<swarm>/<uav>/pose``) into ``table``, with NeighbourTable.update's rules; its id and\n"
"transport age appended to ``srcs`` and ``ages`` if the table took it. Returns 1 (delivered,\n"
"taken or not); None, with nothing changed, if any rule would refuse it (its key names another\n"
"UAV, it is ``own``'s (0: none), it does not decode): the caller then takes it the Python way.");

static PyObject *Intake_take_pose(Intake *self, PyObject *args) {
    PyObject *key, *table, *srcs, *ages;
    Py_buffer buf;
    long long own;
    double at;
    if (!PyArg_ParseTuple(args, "Uy*LO!dO!O!", &key, &buf, &own, &PyDict_Type, &table, &at, &PyList_Type, &srcs,
                          &PyList_Type, &ages))
        return NULL;
    WirePose w;
    Py_ssize_t klen;
    const char *k = PyUnicode_AsUTF8AndSize(key, &klen);
    int clean = k != NULL && read_pose(buf.buf, buf.len, self->pose_tag, &w) == 0 && w.uav == uav_of_key(k, klen) &&
                w.uav != own;
    PyBuffer_Release(&buf);
    if (k == NULL) return NULL;
    if (!clean) Py_RETURN_NONE;
    if (update(self, table, &w, at, srcs, ages) < 0) return NULL;
    return PyLong_FromLong(1);
}

PyDoc_STRVAR(count_doc,
"count(data, exclude) -> int\n\n"
"How many poses an edge-feed batch carries from UAVs other than ``exclude``, as\n"
"swarmnet.messages.batched_pose_count counts them; -1 if the batch is not clean (as take()\n"
"would decline it): the caller then counts the Python way.");

static PyObject *Intake_count(Intake *self, PyObject *args) {
    Py_buffer buf;
    long long exclude, others = 0;
    if (!PyArg_ParseTuple(args, "y*L", &buf, &exclude)) return NULL;
    int clean = read_batch(buf.buf, buf.len, self->batch_tag, self->pose_tag, NULL, exclude, &others);
    PyBuffer_Release(&buf);
    return PyLong_FromLongLong(clean == 1 ? others : -1);
}

static PyMethodDef Intake_methods[] = {
    {"take", (PyCFunction)Intake_take, METH_VARARGS, take_doc},
    {"count", (PyCFunction)Intake_count, METH_VARARGS, count_doc},
    {"take_pose", (PyCFunction)Intake_take_pose, METH_VARARGS, take_pose_doc},
    {NULL, NULL, 0, NULL},
};

PyDoc_STRVAR(Intake_doc,
"Intake(pose_type, neighbour_type, realms, batch_tag, pose_tag)\n\n"
"The compiled fast path of a UAV's edge-feed intake, bound to the Pose and Neighbour classes\n"
"(dataclasses with slots), the Realm of wire values 0 and 1, and the batch's and pose's tags.");

static PyTypeObject IntakeType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "swarmnet._intake.Intake",
    .tp_basicsize = sizeof(Intake),
    .tp_dealloc = (destructor)Intake_dealloc,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = Intake_doc,
    .tp_methods = Intake_methods,
    .tp_init = (initproc)Intake_init,
    .tp_new = PyType_GenericNew,
};

static struct PyModuleDef intake_module = {
    PyModuleDef_HEAD_INIT, "swarmnet._intake",
    "An edge-feed batch into the neighbour table in one compiled pass (see swarmnet/intake.py).", -1, NULL,
};

PyMODINIT_FUNC PyInit__intake(void) {
    if (PyType_Ready(&IntakeType) < 0) return NULL;
    PyObject *m = PyModule_Create(&intake_module);
    if (m == NULL) return NULL;
    Py_INCREF(&IntakeType);
    if (PyModule_AddObject(m, "Intake", (PyObject *)&IntakeType) < 0) {
        Py_DECREF(&IntakeType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
