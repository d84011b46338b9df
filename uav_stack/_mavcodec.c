/* MAVLink 2 framing of the FCU link's plain messages in one compiled pass (see uav_stack/mavcodec.py).
 *
 * pymavlink stays the codec: this module only does, for the messages it is given (no arrays,
 * no strings, unsigned MAVLink 2 frames), what pymavlink's ``MAVLink.decode`` and
 * ``MAVLink_message.pack`` do, with pymavlink's own classes, struct layouts and CRC extras, and
 * it builds objects whose attributes equal pymavlink's, attribute for attribute (the tests
 * compare ``vars()``). Anything else it declines: ``decode`` returns None for a datagram it
 * cannot take whole (a signed or MAVLink 1 frame, an unknown message, a bad CRC, stray bytes),
 * and pymavlink parses it then, naming and counting what is wrong exactly as before; ``pack``
 * hands a message it does not know, or a signing link, to ``msg.pack(mav)``.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>
#include "_x25crc.h"

#define MAGIC_V2 0xFD
#define HEADER_LEN 10
#define CRC_LEN 2
#define MAX_PAYLOAD 255

typedef struct {
    PyObject_HEAD
    PyObject *header_cls;      /* pymavlink's MAVLink_header */
    PyObject *header_template; /* dict: a header's attributes, every one overwritten */
    PyObject *by_id;           /* int msgid -> Spec tuple */
    PyObject *by_cls;          /* class -> Spec tuple */
    PyObject *empty;           /* () */
    PyObject *s_signing, *s_sign_outgoing, *s_seq, *s_src_system, *s_src_component, *s_pack;
    PyObject *s_msgbuf, *s_payload, *s_crc, *s_header, *s_msgid;
    PyObject *s_mlen, *s_hseq, *s_hsys, *s_hcomp, *s_iflags, *s_cflags;
} Codec;

/* A spec tuple: (cls, msgid, crc_extra, unpack, pack, size, wire_names, template) */
enum { SP_CLS, SP_ID, SP_EXTRA, SP_UNPACK, SP_PACK, SP_SIZE, SP_NAMES, SP_TEMPLATE, SP_LEN };

static uint16_t frame_crc(const unsigned char *frame, Py_ssize_t plen, uint8_t extra) {
    uint16_t crc = crc_accumulate(0xFFFF, frame + 1, HEADER_LEN - 1 + plen);
    return crc_accumulate(crc, &extra, 1);
}

static void codec_dealloc(Codec *self) {
    Py_XDECREF(self->header_cls);
    Py_XDECREF(self->header_template);
    Py_XDECREF(self->by_id);
    Py_XDECREF(self->by_cls);
    Py_XDECREF(self->empty);
    PyObject **names[] = {&self->s_signing, &self->s_sign_outgoing, &self->s_seq, &self->s_src_system,
                          &self->s_src_component, &self->s_pack, &self->s_msgbuf, &self->s_payload, &self->s_crc,
                          &self->s_header, &self->s_msgid, &self->s_mlen, &self->s_hseq, &self->s_hsys,
                          &self->s_hcomp, &self->s_iflags, &self->s_cflags};
    for (size_t i = 0; i < sizeof(names) / sizeof(names[0]); i++) Py_XDECREF(*names[i]);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int check_spec(PyObject *spec) {
    if (!PyTuple_Check(spec) || PyTuple_GET_SIZE(spec) != SP_LEN || !PyType_Check(PyTuple_GET_ITEM(spec, SP_CLS))
        || !PyLong_Check(PyTuple_GET_ITEM(spec, SP_ID)) || !PyLong_Check(PyTuple_GET_ITEM(spec, SP_EXTRA))
        || !PyCallable_Check(PyTuple_GET_ITEM(spec, SP_UNPACK)) || !PyCallable_Check(PyTuple_GET_ITEM(spec, SP_PACK))
        || !PyLong_Check(PyTuple_GET_ITEM(spec, SP_SIZE)) || !PyTuple_Check(PyTuple_GET_ITEM(spec, SP_NAMES))
        || !PyDict_Check(PyTuple_GET_ITEM(spec, SP_TEMPLATE))) {
        PyErr_SetString(PyExc_TypeError,
                        "a spec is (cls, msgid, crc_extra, unpack, pack, size, wire_names, template)");
        return -1;
    }
    long size = PyLong_AsLong(PyTuple_GET_ITEM(spec, SP_SIZE));
    if (size < 1 || size > MAX_PAYLOAD) {
        PyErr_SetString(PyExc_ValueError, "a spec's payload size must be 1..255 bytes");
        return -1;
    }
    return 0;
}

static int codec_init(Codec *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"header_cls", "header_template", "specs", NULL};
    PyObject *header_cls, *header_template, *specs;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "OO!O!", kwlist, &header_cls, &PyDict_Type, &header_template,
                                     &PyList_Type, &specs))
        return -1;
    if (!PyType_Check(header_cls)) {
        PyErr_SetString(PyExc_TypeError, "header_cls must be a class");
        return -1;
    }
    PyObject *by_id = PyDict_New(), *by_cls = PyDict_New();
    if (by_id == NULL || by_cls == NULL) goto fail;
    for (Py_ssize_t i = 0; i < PyList_GET_SIZE(specs); i++) {
        PyObject *spec = PyList_GET_ITEM(specs, i);
        if (check_spec(spec) < 0) goto fail;
        if (PyDict_SetItem(by_id, PyTuple_GET_ITEM(spec, SP_ID), spec) < 0) goto fail;
        if (PyDict_SetItem(by_cls, PyTuple_GET_ITEM(spec, SP_CLS), spec) < 0) goto fail;
    }
    Py_INCREF(header_cls);
    Py_XSETREF(self->header_cls, header_cls);
    Py_INCREF(header_template);
    Py_XSETREF(self->header_template, header_template);
    Py_XSETREF(self->by_id, by_id);
    Py_XSETREF(self->by_cls, by_cls);
    Py_XSETREF(self->empty, PyTuple_New(0));
#define INTERN(field, text) Py_XSETREF(self->field, PyUnicode_InternFromString(text))
    INTERN(s_signing, "signing");
    INTERN(s_sign_outgoing, "sign_outgoing");
    INTERN(s_seq, "seq");
    INTERN(s_src_system, "srcSystem");
    INTERN(s_src_component, "srcComponent");
    INTERN(s_pack, "pack");
    INTERN(s_msgbuf, "_msgbuf");
    INTERN(s_payload, "_payload");
    INTERN(s_crc, "_crc");
    INTERN(s_header, "_header");
    INTERN(s_msgid, "msgId");
    INTERN(s_mlen, "mlen");
    INTERN(s_hseq, "seq");
    INTERN(s_hsys, "srcSystem");
    INTERN(s_hcomp, "srcComponent");
    INTERN(s_iflags, "incompat_flags");
    INTERN(s_cflags, "compat_flags");
#undef INTERN
    if (self->empty == NULL || self->s_cflags == NULL) return -1;
    return 0;
fail:
    Py_XDECREF(by_id);
    Py_XDECREF(by_cls);
    return -1;
}

/* A new instance of ``cls`` whose __dict__ is a copy of ``template``, without running __init__. */
static PyObject *new_from_template(Codec *self, PyObject *cls, PyObject *template, PyObject **dict_out) {
    PyTypeObject *tp = (PyTypeObject *)cls;
    PyObject *obj = tp->tp_new(tp, self->empty, NULL);
    if (obj == NULL) return NULL;
    PyObject *dict = PyDict_Copy(template);
    if (dict == NULL || PyObject_GenericSetDict(obj, dict, NULL) < 0) {
        Py_XDECREF(dict);
        Py_DECREF(obj);
        return NULL;
    }
    *dict_out = dict; /* borrowed from here on: the object holds it */
    Py_DECREF(dict);
    return obj;
}

static int set_long(PyObject *dict, PyObject *key, long v) {
    PyObject *o = PyLong_FromLong(v);
    if (o == NULL) return -1;
    int r = PyDict_SetItem(dict, key, o);
    Py_DECREF(o);
    return r;
}

static PyObject *make_header(Codec *self, long msgid, long mlen, long seq, long sys, long comp, long compat) {
    PyObject *d;
    PyObject *h = new_from_template(self, self->header_cls, self->header_template, &d);
    if (h == NULL) return NULL;
    if (set_long(d, self->s_msgid, msgid) < 0 || set_long(d, self->s_mlen, mlen) < 0
        || set_long(d, self->s_hseq, seq) < 0 || set_long(d, self->s_hsys, sys) < 0
        || set_long(d, self->s_hcomp, comp) < 0 || set_long(d, self->s_iflags, 0) < 0
        || set_long(d, self->s_cflags, compat) < 0) {
        Py_DECREF(h);
        return NULL;
    }
    return h;
}

/* One frame (``len`` bytes at ``f``, already checked) as pymavlink's message object. */
static PyObject *decode_frame(Codec *self, PyObject *spec, const unsigned char *f, Py_ssize_t len) {
    Py_ssize_t plen = f[1];
    long size = PyLong_AsLong(PyTuple_GET_ITEM(spec, SP_SIZE));
    unsigned char padded[MAX_PAYLOAD];
    memset(padded, 0, sizeof(padded));
    memcpy(padded, f + HEADER_LEN, (size_t)plen);
    PyObject *buf = PyBytes_FromStringAndSize((const char *)padded, size);
    if (buf == NULL) return NULL;
    PyObject *values = PyObject_CallOneArg(PyTuple_GET_ITEM(spec, SP_UNPACK), buf);
    Py_DECREF(buf);
    if (values == NULL) return NULL;
    PyObject *names = PyTuple_GET_ITEM(spec, SP_NAMES);
    if (!PyTuple_Check(values) || PyTuple_GET_SIZE(values) != PyTuple_GET_SIZE(names)) {
        Py_DECREF(values);
        PyErr_SetString(PyExc_ValueError, "a spec's layout does not match its field names");
        return NULL;
    }
    PyObject *d;
    PyObject *msg = new_from_template(self, PyTuple_GET_ITEM(spec, SP_CLS), PyTuple_GET_ITEM(spec, SP_TEMPLATE), &d);
    if (msg == NULL) {
        Py_DECREF(values);
        return NULL;
    }
    for (Py_ssize_t i = 0; i < PyTuple_GET_SIZE(names); i++) {
        if (PyDict_SetItem(d, PyTuple_GET_ITEM(names, i), PyTuple_GET_ITEM(values, i)) < 0) goto fail;
    }
    Py_CLEAR(values);
    /* as pymavlink's decode sets them (its _payload starts at byte 6 of a MAVLink 2 frame too) */
    PyObject *msgbuf = PyByteArray_FromStringAndSize((const char *)f, len);
    PyObject *payload = PyByteArray_FromStringAndSize((const char *)f + 6, len - 6 - CRC_LEN);
    PyObject *crc = PyLong_FromLong(f[len - 2] | (f[len - 1] << 8));
    long msgid = f[7] | (f[8] << 8) | ((long)f[9] << 16);
    PyObject *header = make_header(self, msgid, plen, f[4], f[5], f[6], f[3]);
    int bad = msgbuf == NULL || payload == NULL || crc == NULL || header == NULL
              || PyDict_SetItem(d, self->s_msgbuf, msgbuf) < 0 || PyDict_SetItem(d, self->s_payload, payload) < 0
              || PyDict_SetItem(d, self->s_crc, crc) < 0 || PyDict_SetItem(d, self->s_header, header) < 0;
    Py_XDECREF(msgbuf);
    Py_XDECREF(payload);
    Py_XDECREF(crc);
    Py_XDECREF(header);
    if (bad) goto fail;
    return msg;
fail:
    Py_XDECREF(values);
    Py_DECREF(msg);
    return NULL;
}

static int ready(Codec *self) {
    if (self->by_id == NULL || self->s_cflags == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "Codec was not initialised");
        return 0;
    }
    return 1;
}

static PyObject *codec_decode(Codec *self, PyObject *arg) {
    if (!ready(self)) return NULL;
    Py_buffer view;
    if (PyObject_GetBuffer(arg, &view, PyBUF_SIMPLE) < 0) return NULL;
    const unsigned char *p = view.buf;
    Py_ssize_t n = view.len, at = 0;
    PyObject *out = NULL;
    if (n == 0) goto decline;
    /* first pass: every frame must be one this pass takes, so a declined datagram costs nothing */
    while (at < n) {
        if (n - at < HEADER_LEN + CRC_LEN || p[at] != MAGIC_V2 || p[at + 2] != 0) goto decline;
        Py_ssize_t len = HEADER_LEN + p[at + 1] + CRC_LEN;
        if (len > n - at) goto decline;
        long msgid = p[at + 7] | (p[at + 8] << 8) | ((long)p[at + 9] << 16);
        PyObject *key = PyLong_FromLong(msgid);
        if (key == NULL) goto error;
        PyObject *spec = PyDict_GetItemWithError(self->by_id, key);
        Py_DECREF(key);
        if (spec == NULL) {
            if (PyErr_Occurred()) goto error;
            goto decline;
        }
        if (p[at + 1] > PyLong_AsLong(PyTuple_GET_ITEM(spec, SP_SIZE))) goto decline;
        uint16_t crc = frame_crc(p + at, p[at + 1], (uint8_t)PyLong_AsLong(PyTuple_GET_ITEM(spec, SP_EXTRA)));
        if (crc != (p[at + len - 2] | (p[at + len - 1] << 8))) goto decline;
        at += len;
    }
    out = PyList_New(0);
    if (out == NULL) goto error;
    for (at = 0; at < n;) {
        Py_ssize_t len = HEADER_LEN + p[at + 1] + CRC_LEN;
        long msgid = p[at + 7] | (p[at + 8] << 8) | ((long)p[at + 9] << 16);
        PyObject *key = PyLong_FromLong(msgid);
        if (key == NULL) goto error;
        PyObject *spec = PyDict_GetItemWithError(self->by_id, key);
        Py_DECREF(key);
        if (spec == NULL) goto error; /* cannot happen: checked above */
        PyObject *msg = decode_frame(self, spec, p + at, len);
        if (msg == NULL) goto error;
        int r = PyList_Append(out, msg);
        Py_DECREF(msg);
        if (r < 0) goto error;
        at += len;
    }
    PyBuffer_Release(&view);
    return out;
decline:
    PyBuffer_Release(&view);
    Py_RETURN_NONE;
error:
    if (!PyErr_Occurred()) PyErr_SetString(PyExc_RuntimeError, "mavcodec: inconsistent table");
    Py_XDECREF(out);
    PyBuffer_Release(&view);
    return NULL;
}

/* An int attribute of ``obj`` in 0..255, or -1 (error set only if the attribute is missing or not an int). */
static long small_attr(PyObject *obj, PyObject *name) {
    PyObject *v = PyObject_GetAttr(obj, name);
    if (v == NULL) return -2;
    long r = PyLong_Check(v) ? PyLong_AsLong(v) : -1;
    Py_DECREF(v);
    if (r == -1 && PyErr_Occurred()) PyErr_Clear();
    return (r >= 0 && r <= 255) ? r : -1;
}

static PyObject *pack_by_pymavlink(Codec *self, PyObject *msg, PyObject *mav) {
    return PyObject_CallMethodOneArg(msg, self->s_pack, mav);
}

static PyObject *codec_pack(Codec *self, PyObject *args) {
    PyObject *msg, *mav;
    if (!ready(self) || !PyArg_ParseTuple(args, "OO", &msg, &mav)) return NULL;
    PyObject *spec = PyDict_GetItemWithError(self->by_cls, (PyObject *)Py_TYPE(msg));
    if (spec == NULL) {
        if (PyErr_Occurred()) return NULL;
        return pack_by_pymavlink(self, msg, mav);
    }
    PyObject *signing = PyObject_GetAttr(mav, self->s_signing);
    if (signing == NULL) return NULL;
    PyObject *outgoing = PyObject_GetAttr(signing, self->s_sign_outgoing);
    Py_DECREF(signing);
    if (outgoing == NULL) return NULL;
    int signs = PyObject_IsTrue(outgoing);
    Py_DECREF(outgoing);
    if (signs < 0) return NULL;
    long seq = small_attr(mav, self->s_seq), sys = small_attr(mav, self->s_src_system),
         comp = small_attr(mav, self->s_src_component);
    if (seq == -2 || sys == -2 || comp == -2) return NULL;
    if (signs || seq < 0 || sys < 0 || comp < 0) return pack_by_pymavlink(self, msg, mav); /* it signs, or raises */

    PyObject *names = PyTuple_GET_ITEM(spec, SP_NAMES);
    Py_ssize_t nf = PyTuple_GET_SIZE(names);
    PyObject *values = PyTuple_New(nf);
    if (values == NULL) return NULL;
    for (Py_ssize_t i = 0; i < nf; i++) {
        PyObject *v = PyObject_GetAttr(msg, PyTuple_GET_ITEM(names, i));
        if (v == NULL) {
            Py_DECREF(values);
            return NULL;
        }
        PyTuple_SET_ITEM(values, i, v);
    }
    PyObject *payload = PyObject_Call(PyTuple_GET_ITEM(spec, SP_PACK), values, NULL); /* struct.error as pymavlink */
    Py_DECREF(values);
    if (payload == NULL) return NULL;
    if (!PyBytes_Check(payload) || PyBytes_GET_SIZE(payload) > MAX_PAYLOAD || PyBytes_GET_SIZE(payload) < 1) {
        Py_DECREF(payload);
        PyErr_SetString(PyExc_ValueError, "a spec's pack gave no payload of 1..255 bytes");
        return NULL;
    }
    const unsigned char *pl = (const unsigned char *)PyBytes_AS_STRING(payload);
    Py_ssize_t plen = PyBytes_GET_SIZE(payload);
    while (plen > 1 && pl[plen - 1] == 0) plen--; /* MAVLink 2 drops trailing zeros */
    long msgid = PyLong_AsLong(PyTuple_GET_ITEM(spec, SP_ID));
    unsigned char frame[HEADER_LEN + MAX_PAYLOAD + CRC_LEN];
    frame[0] = MAGIC_V2;
    frame[1] = (unsigned char)plen;
    frame[2] = 0;
    frame[3] = 0;
    frame[4] = (unsigned char)seq;
    frame[5] = (unsigned char)sys;
    frame[6] = (unsigned char)comp;
    frame[7] = (unsigned char)(msgid & 0xFF);
    frame[8] = (unsigned char)((msgid >> 8) & 0xFF);
    frame[9] = (unsigned char)((msgid >> 16) & 0xFF);
    memcpy(frame + HEADER_LEN, pl, (size_t)plen);
    uint16_t crc = frame_crc(frame, plen, (uint8_t)PyLong_AsLong(PyTuple_GET_ITEM(spec, SP_EXTRA)));
    frame[HEADER_LEN + plen] = (unsigned char)(crc & 0xFF);
    frame[HEADER_LEN + plen + 1] = (unsigned char)(crc >> 8);
    Py_ssize_t flen = HEADER_LEN + plen + CRC_LEN;

    /* what pymavlink's _pack leaves on the message */
    PyObject *trimmed = PyBytes_FromStringAndSize((const char *)pl, plen);
    Py_DECREF(payload);
    PyObject *msgbuf = PyByteArray_FromStringAndSize((const char *)frame, flen);
    PyObject *crc_obj = PyLong_FromLong(crc);
    PyObject *header = make_header(self, msgid, plen, seq, sys, comp, 0);
    PyObject *out = PyBytes_FromStringAndSize((const char *)frame, flen);
    int bad = trimmed == NULL || msgbuf == NULL || crc_obj == NULL || header == NULL || out == NULL
              || PyObject_SetAttr(msg, self->s_payload, trimmed) < 0 || PyObject_SetAttr(msg, self->s_header, header) < 0
              || PyObject_SetAttr(msg, self->s_msgbuf, msgbuf) < 0 || PyObject_SetAttr(msg, self->s_crc, crc_obj) < 0;
    Py_XDECREF(trimmed);
    Py_XDECREF(msgbuf);
    Py_XDECREF(crc_obj);
    Py_XDECREF(header);
    if (bad) {
        Py_XDECREF(out);
        return NULL;
    }
    return out;
}

static PyObject *codec_knows(Codec *self, PyObject *cls) {
    if (!ready(self)) return NULL;
    int r = PyDict_Contains(self->by_cls, cls);
    if (r < 0) return NULL;
    return PyBool_FromLong(r);
}

static PyMethodDef codec_methods[] = {
    {"decode", (PyCFunction)codec_decode, METH_O,
     "decode(datagram) -> list of messages, or None if any frame is not one this pass takes."},
    {"pack", (PyCFunction)codec_pack, METH_VARARGS,
     "pack(msg, mav) -> bytes: the frame msg.pack(mav) gives, with the same attributes left on msg."},
    {"knows", (PyCFunction)codec_knows, METH_O, "knows(cls) -> bool: does this pass frame messages of cls?"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject CodecType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "uav_stack._mavcodec.Codec",
    .tp_basicsize = sizeof(Codec),
    .tp_dealloc = (destructor)codec_dealloc,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Codec(header_cls, header_template, specs): MAVLink 2 framing of plain messages (uav_stack/mavcodec.py).",
    .tp_methods = codec_methods,
    .tp_init = (initproc)codec_init,
    .tp_new = PyType_GenericNew,
};

static struct PyModuleDef mavcodec_module = {
    PyModuleDef_HEAD_INIT, "uav_stack._mavcodec",
    "MAVLink 2 framing of the FCU link's plain messages in one compiled pass (see uav_stack/mavcodec.py).", -1,
    NULL,
};

PyMODINIT_FUNC PyInit__mavcodec(void) {
    if (PyType_Ready(&CodecType) < 0) return NULL;
    PyObject *m = PyModule_Create(&mavcodec_module);
    if (m == NULL) return NULL;
    Py_INCREF(&CodecType);
    if (PyModule_AddObject(m, "Codec", (PyObject *)&CodecType) < 0) {
        Py_DECREF(&CodecType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
