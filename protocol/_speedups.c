/* protocol._speedups: COBS and CRC-16/CCITT-FALSE in C for the frame codec's hot path.
 *
 * The pure-Python modules protocol/cobs.py and protocol/crc.py are the reference; this module computes
 * exactly what they do (tests/test_protocol_speedups.py compares the two on random data and on the test
 * vectors) and protocol/speedups.py chooses between them. Built at install by setup.py as an optional
 * extension: without a C compiler the package installs and runs on the reference.
 *
 * Invalid input is never an exception here: a function that finds it returns None and the caller re-runs
 * the reference, which words the error. So the error text is built only on failure, in one place.
 *
 *   cobs_encode(data) -> bytes            canonical COBS of data (no delimiter), as cobs.encode
 *   cobs_decode(data) -> bytes | None     as cobs.decode, None where it raises
 *   crc16(data, value=0xFFFF) -> int      as crc.crc16_ccitt_false
 *   seal(body) -> bytes                   COBS(body + CRC-16 little-endian) + b"\x00": a frame on the wire
 *   unseal(chunk, min_len, max_len) -> bytes | None
 *                                         chunk (without delimiter) COBS-decoded, its length within
 *                                         [min_len, max_len] and its trailing CRC-16 right: the frame
 *                                         without the CRC; None for anything else
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#define COBS_FULL 254 /* data bytes in a full block (code 0xFF) */

static uint16_t crc_table[256];

static void crc_table_init(void) {
    for (unsigned i = 0; i < 256; i++) {
        uint16_t crc = (uint16_t)(i << 8);
        for (int bit = 0; bit < 8; bit++) {
            crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
        }
        crc_table[i] = crc;
    }
}

static uint16_t crc_update(uint16_t crc, const uint8_t *p, Py_ssize_t n) {
    while (n-- > 0) {
        crc = (uint16_t)((crc << 8) ^ crc_table[((crc >> 8) ^ *p++) & 0xFF]);
    }
    return crc;
}

static Py_ssize_t cobs_max_encoded(Py_ssize_t n) { return n + n / COBS_FULL + 1; }

/* Streaming COBS encoder writing into a buffer of at least cobs_max_encoded(n) bytes. */
typedef struct {
    uint8_t *out;  /* next free byte */
    uint8_t *code; /* the current group's code byte */
    uint8_t count; /* code value so far: 1 + data bytes in the group */
} cobs_writer;

static void cobs_start(cobs_writer *w, uint8_t *buf) {
    w->code = buf;
    w->out = buf + 1;
    w->count = 1;
}

static void cobs_put(cobs_writer *w, const uint8_t *p, Py_ssize_t n) {
    for (Py_ssize_t i = 0; i < n; i++) {
        uint8_t b = p[i];
        if (b == 0) {
            *w->code = w->count;
            w->code = w->out++;
            w->count = 1;
            continue;
        }
        *w->out++ = b;
        if (++w->count == 0xFF) { /* a full block: closed without standing for a zero */
            *w->code = 0xFF;
            w->code = w->out++;
            w->count = 1;
        }
    }
}

static uint8_t *cobs_finish(cobs_writer *w) {
    *w->code = w->count;
    return w->out;
}

/* COBS-decode src[0:n] into dst (room for n bytes). Returns the decoded length, or -1 if invalid. */
static Py_ssize_t cobs_unstuff(const uint8_t *src, Py_ssize_t n, uint8_t *dst) {
    if (memchr(src, 0, (size_t)n) != NULL) {
        return -1;
    }
    Py_ssize_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = src[i];
        Py_ssize_t end = i + code;
        if (end > n) {
            return -1;
        }
        memcpy(dst + o, src + i + 1, (size_t)(code - 1));
        o += code - 1;
        i = end;
        if (code != 0xFF && i < n) {
            dst[o++] = 0;
        }
    }
    return o;
}

/* ------------------------------------------------------------------ Python functions */
static PyObject *py_cobs_encode(PyObject *self, PyObject *arg) {
    (void)self;
    Py_buffer view;
    if (PyObject_GetBuffer(arg, &view, PyBUF_SIMPLE) < 0) {
        return NULL;
    }
    PyObject *result = PyBytes_FromStringAndSize(NULL, cobs_max_encoded(view.len));
    if (result != NULL) {
        uint8_t *buf = (uint8_t *)PyBytes_AS_STRING(result);
        cobs_writer w;
        cobs_start(&w, buf);
        cobs_put(&w, (const uint8_t *)view.buf, view.len);
        Py_ssize_t len = cobs_finish(&w) - buf;
        if (_PyBytes_Resize(&result, len) < 0) {
            result = NULL;
        }
    }
    PyBuffer_Release(&view);
    return result;
}

static PyObject *py_cobs_decode(PyObject *self, PyObject *arg) {
    (void)self;
    Py_buffer view;
    if (PyObject_GetBuffer(arg, &view, PyBUF_SIMPLE) < 0) {
        return NULL;
    }
    PyObject *result = PyBytes_FromStringAndSize(NULL, view.len);
    if (result != NULL) {
        Py_ssize_t len = cobs_unstuff((const uint8_t *)view.buf, view.len, (uint8_t *)PyBytes_AS_STRING(result));
        if (len < 0) {
            Py_DECREF(result);
            result = Py_NewRef(Py_None);
        } else if (_PyBytes_Resize(&result, len) < 0) {
            result = NULL;
        }
    }
    PyBuffer_Release(&view);
    return result;
}

static PyObject *py_crc16(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs < 1 || nargs > 2) {
        PyErr_SetString(PyExc_TypeError, "crc16(data, value=0xFFFF) takes 1 or 2 arguments");
        return NULL;
    }
    unsigned long value = 0xFFFF;
    if (nargs == 2) {
        value = PyLong_AsUnsignedLong(args[1]);
        if (value == (unsigned long)-1 && PyErr_Occurred()) {
            return NULL;
        }
        if (value > 0xFFFF) {
            PyErr_SetString(PyExc_ValueError, "crc16: value must be in 0..0xFFFF");
            return NULL;
        }
    }
    Py_buffer view;
    if (PyObject_GetBuffer(args[0], &view, PyBUF_SIMPLE) < 0) {
        return NULL;
    }
    uint16_t crc = crc_update((uint16_t)value, (const uint8_t *)view.buf, view.len);
    PyBuffer_Release(&view);
    return PyLong_FromUnsignedLong(crc);
}

static PyObject *py_seal(PyObject *self, PyObject *arg) {
    (void)self;
    Py_buffer view;
    if (PyObject_GetBuffer(arg, &view, PyBUF_SIMPLE) < 0) {
        return NULL;
    }
    uint16_t crc = crc_update(0xFFFF, (const uint8_t *)view.buf, view.len);
    uint8_t crc_le[2] = {(uint8_t)(crc & 0xFF), (uint8_t)(crc >> 8)};
    PyObject *result = PyBytes_FromStringAndSize(NULL, cobs_max_encoded(view.len + 2) + 1);
    if (result != NULL) {
        uint8_t *buf = (uint8_t *)PyBytes_AS_STRING(result);
        cobs_writer w;
        cobs_start(&w, buf);
        cobs_put(&w, (const uint8_t *)view.buf, view.len);
        cobs_put(&w, crc_le, 2);
        uint8_t *end = cobs_finish(&w);
        *end++ = 0; /* the delimiter */
        if (_PyBytes_Resize(&result, end - buf) < 0) {
            result = NULL;
        }
    }
    PyBuffer_Release(&view);
    return result;
}

static PyObject *py_unseal(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "unseal(chunk, min_len, max_len) takes 3 arguments");
        return NULL;
    }
    Py_ssize_t min_len = PyLong_AsSsize_t(args[1]);
    if (min_len == -1 && PyErr_Occurred()) {
        return NULL;
    }
    Py_ssize_t max_len = PyLong_AsSsize_t(args[2]);
    if (max_len == -1 && PyErr_Occurred()) {
        return NULL;
    }
    if (min_len < 2) {
        PyErr_SetString(PyExc_ValueError, "unseal: min_len must be at least 2 (the CRC)");
        return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(args[0], &view, PyBUF_SIMPLE) < 0) {
        return NULL;
    }
    PyObject *result = PyBytes_FromStringAndSize(NULL, view.len);
    if (result != NULL) {
        uint8_t *buf = (uint8_t *)PyBytes_AS_STRING(result);
        Py_ssize_t len = cobs_unstuff((const uint8_t *)view.buf, view.len, buf);
        int ok = len >= min_len && len <= max_len;
        if (ok) {
            uint16_t received = (uint16_t)(buf[len - 2] | (buf[len - 1] << 8));
            ok = received == crc_update(0xFFFF, buf, len - 2);
        }
        if (!ok) {
            Py_DECREF(result);
            result = Py_NewRef(Py_None);
        } else if (_PyBytes_Resize(&result, len - 2) < 0) {
            result = NULL;
        }
    }
    PyBuffer_Release(&view);
    return result;
}

static PyMethodDef methods[] = {
    {"cobs_encode", py_cobs_encode, METH_O, "Canonical COBS of a bytes-like object (no delimiter)."},
    {"cobs_decode", py_cobs_decode, METH_O, "COBS-decoded bytes, or None if the input is not valid COBS."},
    {"crc16", (PyCFunction)(void (*)(void))py_crc16, METH_FASTCALL,
     "CRC-16/CCITT-FALSE of data, continuing from value (default 0xFFFF)."},
    {"seal", py_seal, METH_O, "COBS(body + CRC-16 little-endian) + b'\\x00'."},
    {"unseal", (PyCFunction)(void (*)(void))py_unseal, METH_FASTCALL,
     "The frame in a COBS chunk without its CRC, or None if the COBS, length or CRC is wrong."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "protocol._speedups",
    .m_doc = "COBS and CRC-16 in C (see protocol/speedups.py).",
    .m_size = -1,
    .m_methods = methods,
};

PyMODINIT_FUNC PyInit__speedups(void) {
    crc_table_init();
    return PyModule_Create(&module);
}
