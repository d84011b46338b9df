/*
 * swarmnet._receive: the loop of an inlet's receive thread (swarmnet.receive.Inlet._receive), compiled.
 *
 * Why: a UAV of 50 on the edge feed wakes its pose inlet's thread for each of the feed's two or
 * three batches an instant. Each wake-up ran about forty lines of Python (stamp, the burst, the
 * lock, the expectation's count through two Python calls, a generator per count) with the caches
 * cold: the thread was 9 % of the UAV's CPU, a fifth of it in the interpreter's loop
 * (docs/benchmarks.md). This is the same loop with no Python of its own between the calls it
 * must make (the channel's recv and try_recv, the deque, the lock, the wakers).
 *
 * It keeps the Python loop's contract exactly, and works on the Inlet's own attributes, so that
 * Inlet.expect() and the owner's drain need no change: each sample is stamped (wall time, s) as
 * it leaves the channel; a burst is queued and counted under the inlet's lock; the quorum waker
 * is notified once the expected items have come; the inlet's waker, if any, after every burst.
 * Counting a sample: one, or what the inlet's weigh says; weigh.fast_count(payload, me) first
 * when it has one (the compiled count of a batch's poses), weigh(sample) when that declines
 * (-1). A count that fails counts 0, as Inlet._weight does. The loop ends, returning None, when
 * the channel raises the ZError of a closed subscription or session.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <time.h>

/* time.time()'s value: CLOCK_REALTIME in ns, as a double of seconds the way CPython converts it */
static double wall_now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    int64_t ns = (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
    return (double)ns / 1e9;
}

typedef struct {
    PyObject *clock;      /* NULL: wall_now() (the inlet's clock is time.time) */
    PyObject *weigh;      /* NULL: one per sample */
    PyObject *fast_count; /* NULL: weigh(sample) only */
    PyObject *me;         /* the exclude argument of fast_count */
} Rules;

/* the sample's arrival time, or -1 with an exception set */
static int stamp(const Rules *r, double *at) {
    if (r->clock == NULL) {
        *at = wall_now();
        return 0;
    }
    PyObject *t = PyObject_CallNoArgs(r->clock);
    if (t == NULL) return -1;
    *at = PyFloat_AsDouble(t);
    Py_DECREF(t);
    return (*at == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

/* how many items one sample carries; -1 with an exception set when the count failed */
static long long weight_of(const Rules *r, PyObject *sample) {
    if (r->weigh == NULL) return 1;
    if (r->fast_count != NULL) {
        PyObject *payload = PyObject_GetAttrString(sample, "payload");
        if (payload == NULL) return -1;
        PyObject *data = PyObject_CallMethod(payload, "to_bytes", NULL);
        Py_DECREF(payload);
        if (data == NULL) return -1;
        PyObject *n = PyObject_CallFunctionObjArgs(r->fast_count, data, r->me, NULL);
        Py_DECREF(data);
        if (n == NULL) return -1;
        long long k = PyLong_AsLongLong(n);
        Py_DECREF(n);
        if (k == -1 && PyErr_Occurred()) return -1;
        if (k >= 0) return k;
    }
    PyObject *n = PyObject_CallOneArg(r->weigh, sample);
    if (n == NULL) return -1;
    long long k = PyLong_AsLongLong(n);
    Py_DECREF(n);
    return (k == -1 && PyErr_Occurred()) ? -1 : k;
}

/* Inlet._weight of a burst: the sum, or 0 when any count fails (the error cleared) */
static long long weight_of_burst(const Rules *r, PyObject *burst) {
    long long total = 0;
    Py_ssize_t n = PyList_GET_SIZE(burst);
    for (Py_ssize_t i = 0; i < n; i++) {
        long long k = weight_of(r, PyTuple_GET_ITEM(PyList_GET_ITEM(burst, i), 1));
        if (k < 0) {
            PyErr_Clear();
            return 0;
        }
        total += k;
    }
    return total;
}

/* append (stamp, sample) to the burst; steals sample */
static int add(const Rules *r, PyObject *burst, PyObject *sample, double *at) {
    if (stamp(r, at) < 0) {
        Py_DECREF(sample);
        return -1;
    }
    PyObject *t = PyFloat_FromDouble(*at);
    if (t == NULL) {
        Py_DECREF(sample);
        return -1;
    }
    PyObject *pair = PyTuple_Pack(2, t, sample);
    Py_DECREF(t);
    Py_DECREF(sample);
    if (pair == NULL) return -1;
    int rc = PyList_Append(burst, pair);
    Py_DECREF(pair);
    return rc;
}

/* queue and count a burst under the inlet's lock; the quorum waker to notify (new reference) in *reached */
static int queue_burst(PyObject *inlet, const Rules *r, PyObject *extend, PyObject *lock, PyObject *burst, double at,
                       PyObject **reached) {
    *reached = NULL;
    PyObject *ok = PyObject_CallMethod(lock, "acquire", NULL);
    if (ok == NULL) return -1;
    Py_DECREF(ok);
    int rc = -1;
    PyObject *res = PyObject_CallOneArg(extend, burst);
    if (res == NULL) goto release;
    Py_DECREF(res);
    PyObject *short_o = PyObject_GetAttrString(inlet, "_short");
    if (short_o == NULL) goto release;
    long long short_n = PyLong_AsLongLong(short_o);
    Py_DECREF(short_o);
    if (short_n == -1 && PyErr_Occurred()) goto release;
    if (short_n) {
        PyObject *since_o = PyObject_GetAttrString(inlet, "_since");
        if (since_o == NULL) goto release;
        double since = PyFloat_AsDouble(since_o);
        Py_DECREF(since_o);
        if (since == -1.0 && PyErr_Occurred()) goto release;
        if (at >= since) {
            short_n -= weight_of_burst(r, burst);
            if (short_n < 0) short_n = 0;
            PyObject *v = PyLong_FromLongLong(short_n);
            if (v == NULL) goto release;
            int set = PyObject_SetAttrString(inlet, "_short", v);
            Py_DECREF(v);
            if (set < 0) goto release;
            if (short_n == 0) {
                *reached = PyObject_GetAttrString(inlet, "_quorum_waker");
                if (*reached == NULL) goto release;
            }
        }
    }
    rc = 0;
release:;
    /* released whatever happened, the exception (if any) kept across the call */
    PyObject *et, *ev, *tb;
    PyErr_Fetch(&et, &ev, &tb);
    PyObject *done = PyObject_CallMethod(lock, "release", NULL);
    if (done == NULL) {
        if (et != NULL) {
            PyErr_Clear();
            PyErr_Restore(et, ev, tb);
        }
        Py_CLEAR(*reached);
        return -1;
    }
    Py_DECREF(done);
    PyErr_Restore(et, ev, tb);
    if (rc < 0) Py_CLEAR(*reached);
    return rc;
}

static int notify(PyObject *waker) {
    if (waker == NULL || waker == Py_None) return 0;
    PyObject *res = PyObject_CallMethod(waker, "notify", NULL);
    if (res == NULL) return -1;
    Py_DECREF(res);
    return 0;
}

PyDoc_STRVAR(receive_doc,
"receive(inlet, channel, closed, wall_clock, fast_count, me) -> None\n\n"
"Inlet._receive's loop: take samples from ``channel`` (a Zenoh ring channel's handler) until it\n"
"raises ``closed`` (zenoh.ZError), stamping, queueing and counting them into ``inlet`` as the\n"
"Python loop does. ``wall_clock``: the inlet's clock is time.time (stamped here, the same value);\n"
"else the clock is called. ``fast_count``: a compiled count of a sample's items (payload, me) -> int\n"
"tried before the inlet's weigh, or None.");

static PyObject *receive(PyObject *mod, PyObject *args) {
    PyObject *inlet, *channel, *closed, *fast_count, *me;
    int wall_clock;
    if (!PyArg_ParseTuple(args, "OOOpOO", &inlet, &channel, &closed, &wall_clock, &fast_count, &me)) return NULL;
    PyObject *recv = NULL, *try_recv = NULL, *q = NULL, *extend = NULL, *lock = NULL, *clock = NULL, *weigh = NULL,
             *waker = NULL;
    PyObject *result = NULL;
    Rules r = {NULL, NULL, NULL, me};
    if ((recv = PyObject_GetAttrString(channel, "recv")) == NULL) goto out;
    if ((try_recv = PyObject_GetAttrString(channel, "try_recv")) == NULL) goto out;
    if ((q = PyObject_GetAttrString(inlet, "_q")) == NULL) goto out;
    if ((extend = PyObject_GetAttrString(q, "extend")) == NULL) goto out;
    if ((lock = PyObject_GetAttrString(inlet, "_lock")) == NULL) goto out;
    if ((waker = PyObject_GetAttrString(inlet, "waker")) == NULL) goto out;
    if ((weigh = PyObject_GetAttrString(inlet, "weigh")) == NULL) goto out;
    if (!wall_clock && (clock = PyObject_GetAttrString(inlet, "clock")) == NULL) goto out;
    r.clock = clock;
    r.weigh = weigh == Py_None ? NULL : weigh;
    r.fast_count = fast_count == Py_None ? NULL : fast_count;
    for (;;) {
        PyObject *sample = PyObject_CallNoArgs(recv); /* blocks, the interpreter's lock released */
        if (sample == NULL) {
            if (PyErr_ExceptionMatches(closed)) {
                PyErr_Clear();
                result = Py_NewRef(Py_None);
            }
            goto out;
        }
        PyObject *burst = PyList_New(0);
        if (burst == NULL) {
            Py_DECREF(sample);
            goto out;
        }
        double at, later;
        if (add(&r, burst, sample, &at) < 0) {
            Py_DECREF(burst);
            goto out;
        }
        for (;;) { /* those that came meanwhile: one wake-up */
            PyObject *more = PyObject_CallNoArgs(try_recv);
            if (more == NULL) {
                Py_DECREF(burst);
                if (PyErr_ExceptionMatches(closed)) {
                    PyErr_Clear();
                    result = Py_NewRef(Py_None);
                }
                goto out;
            }
            if (more == Py_None) {
                Py_DECREF(more);
                break;
            }
            if (add(&r, burst, more, &later) < 0) {
                Py_DECREF(burst);
                goto out;
            }
        }
        PyObject *reached = NULL;
        int rc = queue_burst(inlet, &r, extend, lock, burst, at, &reached);
        Py_DECREF(burst);
        if (rc < 0) goto out;
        rc = notify(reached);
        Py_XDECREF(reached);
        if (rc < 0 || notify(waker) < 0) goto out;
    }
out:
    Py_XDECREF(recv);
    Py_XDECREF(try_recv);
    Py_XDECREF(q);
    Py_XDECREF(extend);
    Py_XDECREF(lock);
    Py_XDECREF(clock);
    Py_XDECREF(weigh);
    Py_XDECREF(waker);
    return result;
}

static PyMethodDef receive_methods[] = {
    {"receive", receive, METH_VARARGS, receive_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef receive_module = {
    PyModuleDef_HEAD_INIT, "swarmnet._receive",
    "An inlet's receive thread in one compiled loop (see swarmnet/receive.py).", -1, receive_methods,
};

PyMODINIT_FUNC PyInit__receive(void) { return PyModule_Create(&receive_module); }
