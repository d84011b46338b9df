/* Every datagram pending on a non-blocking UDP socket, in one call (see uav_stack/udp.py).
 *
 * A virtual UAV's loop reads four UDP sockets each tick (its FCU's, its FCU link's, its
 * ground-station endpoints'), most of the time to find one datagram or none. In Python each
 * read that finds none raises BlockingIOError (an exception object, its errno and message),
 * and each datagram costs a loop turn. This does the same reads in C: recvfrom(MSG_DONTWAIT)
 * until the socket is empty, skipping the errors an earlier send left (ECONNREFUSED is counted
 * for the caller), exactly as uav_stack.udp.drain's Python loop does.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <sys/socket.h>

#define MAX_DATAGRAM 65535

static PyObject *address(const struct sockaddr_storage *sa) {
    char host[INET6_ADDRSTRLEN];
    if (sa->ss_family == AF_INET) {
        const struct sockaddr_in *in = (const struct sockaddr_in *)sa;
        if (inet_ntop(AF_INET, &in->sin_addr, host, sizeof host) == NULL) return NULL;
        return Py_BuildValue("(si)", host, (int)ntohs(in->sin_port));
    }
    if (sa->ss_family == AF_INET6) {
        const struct sockaddr_in6 *in6 = (const struct sockaddr_in6 *)sa;
        if (inet_ntop(AF_INET6, &in6->sin6_addr, host, sizeof host) == NULL) return NULL;
        return Py_BuildValue("(si)", host, (int)ntohs(in6->sin6_port));
    }
    return Py_BuildValue("(si)", "", 0);
}

static PyObject *recv_all(PyObject *self, PyObject *args) {
    int fd;
    Py_ssize_t max_datagrams;
    if (!PyArg_ParseTuple(args, "in", &fd, &max_datagrams)) return NULL;
    PyObject *out = PyList_New(0);
    if (out == NULL) return NULL;
    long refused = 0;
    static char buf[MAX_DATAGRAM]; /* one for all calls: the interpreter's lock is held throughout */
    for (Py_ssize_t i = 0; i < max_datagrams; i++) {
        struct sockaddr_storage sa;
        socklen_t len = sizeof sa;
        ssize_t n = recvfrom(fd, buf, sizeof buf, MSG_DONTWAIT, (struct sockaddr *)&sa, &len);
        if (n < 0) {
            if (errno == EAGAIN || errno == EWOULDBLOCK) break;
            if (errno == EINTR) {
                if (PyErr_CheckSignals() < 0) goto error;  /* a handler that raised: as socket.recvfrom would */
                break;  /* as uav_stack.udp.drain: an interrupted read ends this drain */
            }
            if (errno == ECONNREFUSED) refused++;
            if (errno == EBADF || errno == ENOTSOCK) {  /* a closed socket is a bug of the caller: say so */
                PyErr_SetFromErrno(PyExc_OSError);
                goto error;
            }
            continue;  /* an error for an earlier send: not data */
        }
        PyObject *data = PyBytes_FromStringAndSize(buf, n);
        if (data == NULL) goto error;
        PyObject *addr = address(&sa);
        if (addr == NULL) {
            Py_DECREF(data);
            goto error;
        }
        PyObject *item = PyTuple_Pack(2, data, addr);
        Py_DECREF(data);
        Py_DECREF(addr);
        if (item == NULL) goto error;
        int r = PyList_Append(out, item);
        Py_DECREF(item);
        if (r < 0) goto error;
    }
    return Py_BuildValue("(Nl)", out, refused);
error:
    Py_DECREF(out);
    return NULL;
}

static PyMethodDef udp_methods[] = {
    {"recv_all", recv_all, METH_VARARGS,
     "recv_all(fd, max_datagrams) -> ([(bytes, (host, port)), ...], refused): every datagram pending on a "
     "non-blocking UDP socket (at most max_datagrams), and how many ECONNREFUSED it skipped."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef udp_module = {
    PyModuleDef_HEAD_INIT, "uav_stack._udp",
    "The pending datagrams of a UDP socket in one call (see uav_stack/udp.py).", -1, udp_methods,
};

PyMODINIT_FUNC PyInit__udp(void) { return PyModule_Create(&udp_module); }
