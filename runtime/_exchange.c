/* The exchange of one cyclic frame on a raw socket, compiled: ecatcfg.runtime._exchange.
 *
 * Why C: on one CPU a cycle of the pure-Python path costs about 1.5x SOEM's (docs/
 * BENCHMARKS.md, "Cyclic"); most of the difference is the interpreter around the two
 * system calls (the socket module's argument parsing and result objects, the deadline
 * arithmetic in floats, the reply's shape check).  This module does only what the
 * Python path in runtime/master/transport.py (Transport.exchange_prepared with
 * RawLink.recv_into, and _Prepared.fill, matches and take in cyclic.py) does between
 * "the outputs are set" and "the inputs are in the image": it is optional, and the Python
 * path stays the reference (tests/test_compiled_exchange.py runs both on the same frames).
 *
 * exchange(sock, (frame, index_at, shape, out_table, outputs, in_table, inputs), reply,
 *          idx, timeout) -> (size, strays)
 *   sock      the RawLink's socket object (its fileno() is -1 once closed: never an fd
 *             number that another file may have taken since)
 *   frame     bytearray, the prepared frame; idx is written at each offset of index_at
 *   index_at  bytes, one offset per datagram, two bytes little-endian each
 *   reply     bytearray the reply is received into
 *   shape     bytes, as long as the reply must be at least: per byte, the bits in which
 *             the reply must equal the frame as sent (EtherType, EtherCAT header, each
 *             datagram's command, index and length; 0 elsewhere: data, WKC, addresses
 *             the slaves fill in, the circulating bit)
 *   timeout   seconds to wait for the reply
 *   out_table, outputs, in_table, inputs: the process data copied into the frame before
 *             it is sent and out of the reply once it matched (see copy_table)
 *   size      the reply's length, 0 if the frame was lost (no matching reply in time)
 *   strays    replies received that did not match (Transport.counters.stray_replies)
 * A failed send or receive raises OSError with filename "send" or "recv", which the
 * caller turns into the link's own error, as the Python path does.
 *
 * The GIL is released while the socket is used: a cycling thread blocked in recv must
 * not stop the application's other threads.  The frame and the reply buffer are held
 * with PyObject_GetBuffer meanwhile, so no other thread can resize them (a bytearray with
 * an export refuses to); index_at and shape, also read then, are bytes (immutable, kept
 * alive by the caller's tuple); the images are touched only with the GIL held.  Nothing
 * is allocated per call beyond the result (small ints are cached; the tuple comes from
 * CPython's free list).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <errno.h>
#include <poll.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <linux/if_packet.h>

static double monotonic_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);    /* the clock of time.monotonic() */
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Whether reply[:size] is the frame come back: every bit that shape names as sent. */
static int matches(const unsigned char *reply, Py_ssize_t size,
                   const unsigned char *frame, const unsigned char *shape, Py_ssize_t n)
{
    if (size < n)
        return 0;                           /* a short frame is a stray, as in Python */
    for (Py_ssize_t i = 0; i < n; i++)
        if ((reply[i] ^ frame[i]) & shape[i])
            return 0;
    return 1;
}

/* Copy n bytes for each (to, from, n) triple of int32 in table, checked against both
 * buffers' lengths (a memoryview assignment in Python raises ValueError alike). */
static int copy_table(const char *table, Py_ssize_t table_len, unsigned char *to,
                      Py_ssize_t to_len, const unsigned char *from, Py_ssize_t from_len,
                      int from_is_image)
{
    Py_ssize_t count = table_len / (Py_ssize_t)(3 * sizeof(int));
    for (Py_ssize_t k = 0; k < count; k++) {
        int t[3];                           /* (frame or reply offset, image offset, length) */
        memcpy(t, table + k * (Py_ssize_t)sizeof t, sizeof t);   /* bytes: maybe unaligned */
        Py_ssize_t at = t[0], image_at = t[1], n = t[2];
        Py_ssize_t to_at = from_is_image ? at : image_at;
        Py_ssize_t from_at = from_is_image ? image_at : at;
        if (at < 0 || image_at < 0 || n < 0 || to_at + n > to_len || from_at + n > from_len) {
            PyErr_SetString(PyExc_ValueError,
                            "a cyclic command's data lies outside the process image");
            return -1;
        }
        memcpy(to + to_at, from + from_at, (size_t)n);
    }
    return 0;
}

/* The bytes of a bytes object (want_bytearray 0) or of a bytearray (1), read while the
 * GIL is held: cheaper than a buffer export; the frame and the reply buffer, used
 * without the GIL, are exported instead (PyObject_GetBuffer). */
static int bytes_of(PyObject *o, int want_bytearray, char **data, Py_ssize_t *len)
{
    if (want_bytearray ? !PyByteArray_CheckExact(o) : !PyBytes_CheckExact(o)) {
        PyErr_Format(PyExc_TypeError, "exchange: expected %s, got %.100s",
                     want_bytearray ? "bytearray" : "bytes", Py_TYPE(o)->tp_name);
        return -1;
    }
    *data = want_bytearray ? PyByteArray_AS_STRING(o) : PyBytes_AS_STRING(o);
    *len = want_bytearray ? PyByteArray_GET_SIZE(o) : PyBytes_GET_SIZE(o);
    return 0;
}

/* exchange(sock, prepared, reply, idx, timeout) -> (size, strays), prepared being the
 * tuple (frame, index_at, shape, out_table, outputs, in_table, inputs) made once per
 * frame and images (_Prepared.compiled: one argument instead of seven attribute reads).
 * out_table/in_table: int32 triples (offset in the frame or reply, offset in the image,
 * length): the output image is copied into the frame before it is sent, and the reply's
 * read data into the input image once it matched (_Prepared.fill and take in Python). */
static PyObject *exchange(PyObject *Py_UNUSED(self), PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5 || !PyTuple_Check(args[1]) || PyTuple_GET_SIZE(args[1]) != 7) {
        PyErr_SetString(PyExc_TypeError,
                        "exchange(sock, (frame, index_at, shape, out_table, outputs, "
                        "in_table, inputs), reply, idx, timeout)");
        return NULL;
    }
    /* The frame and the reply buffer are used without the GIL: held (and so not
     * resizable by another thread) until the end, released in reverse. */
    enum { FRAME, REPLY, NBUF };
    Py_buffer b[NBUF];
    int held = 0;
    PyObject *result = NULL;
    PyObject *const *prep = &PyTuple_GET_ITEM(args[1], 0);
    for (; held < NBUF; held++)
        if (PyObject_GetBuffer(held == REPLY ? args[2] : prep[0], &b[held],
                               PyBUF_WRITABLE) < 0)
            goto done;
    /* The rest only while the GIL is held. */
    char *at_, *mask_, *out_table, *outputs, *in_table, *inputs;
    Py_ssize_t at_len, shape_len, out_table_len, outputs_len, in_table_len, inputs_len;
    if (bytes_of(prep[1], 0, &at_, &at_len) < 0 || bytes_of(prep[2], 0, &mask_, &shape_len) < 0
            || bytes_of(prep[3], 0, &out_table, &out_table_len) < 0
            || bytes_of(prep[4], 1, &outputs, &outputs_len) < 0
            || bytes_of(prep[5], 0, &in_table, &in_table_len) < 0
            || bytes_of(prep[6], 1, &inputs, &inputs_len) < 0)
        goto done;
    long idx = PyLong_AsLong(args[3]);
    double timeout = PyFloat_AsDouble(args[4]);
    if (PyErr_Occurred())
        goto done;
    unsigned char *f = b[FRAME].buf, *r = b[REPLY].buf;
    const unsigned char *at = (const unsigned char *)at_, *mask = (const unsigned char *)mask_;
    Py_ssize_t frame_len = b[FRAME].len, reply_len = b[REPLY].len;
    if (shape_len > frame_len || shape_len > reply_len) {
        PyErr_SetString(PyExc_ValueError, "shape longer than the frame or the reply buffer");
        goto done;
    }
    for (Py_ssize_t k = 0; k + 1 < at_len; k += 2) {
        Py_ssize_t pos = at[k] | at[k + 1] << 8;
        if (pos >= frame_len) {
            PyErr_SetString(PyExc_ValueError, "index offset past the frame");
            goto done;
        }
        f[pos] = (unsigned char)idx;
    }
    if (copy_table(out_table, out_table_len, f, frame_len, (unsigned char *)outputs,
                   outputs_len, 1) < 0)
        goto done;
    int fd = PyObject_AsFileDescriptor(args[0]);
    if (fd < 0) {
        /* A closed socket's fileno() is -1 (a ValueError here): the error of a send on a
         * closed socket, which the link reports as closed. */
        if (PyErr_ExceptionMatches(PyExc_ValueError)) {
            PyErr_Clear();
            errno = EBADF;
            PyErr_SetFromErrnoWithFilename(PyExc_OSError, "send");
        }
        goto done;
    }
    ssize_t got = 0;
    long strays = 0;
    int err = 0, failed_send = 0;
    Py_BEGIN_ALLOW_THREADS
    double deadline = monotonic_now() + timeout;
    if (send(fd, f, (size_t)frame_len, 0) < 0) {
        err = errno;
        failed_send = 1;
    }
    while (!err) {
        struct sockaddr_ll from;
        socklen_t fromlen = sizeof from;
        from.sll_pkttype = PACKET_HOST;     /* a socket without this field leaves it */
        /* Non-blocking first: on one CPU the reply is usually back when send returns
         * (two system calls, as SOEM's cycle); else wait in poll until the deadline. */
        got = recvfrom(fd, r, (size_t)reply_len, MSG_DONTWAIT, (struct sockaddr *)&from,
                       &fromlen);
        if (got >= 0) {
            /* Our own frame (a kernel without PACKET_IGNORE_OUTGOING): not a reply. */
            if (from.sll_pkttype == PACKET_OUTGOING)
                continue;
            if (matches(r, got, f, mask, shape_len))
                break;
            strays++;                       /* late, foreign or malformed: keep waiting */
            continue;
        }
        if (errno == EINTR)
            continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK) {
            err = errno;
            break;
        }
        double left = deadline - monotonic_now();
        if (left <= 0) {
            got = 0;                        /* lost: Transport counts it */
            break;
        }
        struct pollfd p = {fd, POLLIN, 0};
        /* rounded up: never give up early (nor wait past a day on a huge timeout) */
        int ms = left > 86400.0 ? 86400000 : (int)(left * 1000.0) + 1;
        if (poll(&p, 1, ms) < 0 && errno != EINTR) {
            err = errno;
            break;
        }
    }
    Py_END_ALLOW_THREADS
    if (err) {
        errno = err;
        PyErr_SetFromErrnoWithFilename(PyExc_OSError, failed_send ? "send" : "recv");
        goto done;
    }
    /* Another thread may have resized the input image while the GIL was released:
     * its bytes are looked up again, now that the GIL is held. */
    if (got > 0 && bytes_of(prep[6], 1, &inputs, &inputs_len) < 0)
        goto done;
    if (got > 0 && copy_table(in_table, in_table_len, (unsigned char *)inputs, inputs_len, r,
                              got, 0) < 0)
        goto done;
    /* Built by hand: Py_BuildValue parses its format string on every call. */
    PyObject *size = PyLong_FromSsize_t((Py_ssize_t)got), *stray = PyLong_FromLong(strays);
    if (size != NULL && stray != NULL)
        result = PyTuple_Pack(2, size, stray);
    Py_XDECREF(size);
    Py_XDECREF(stray);
done:
    while (held > 0)
        PyBuffer_Release(&b[--held]);
    return result;
}

static PyMethodDef methods[] = {
    {"exchange", (PyCFunction)(void (*)(void))exchange, METH_FASTCALL,
     "exchange(sock, (frame, index_at, shape, out_table, outputs, in_table, inputs), reply, "
     "idx, timeout) -> (size, strays): fill, send the prepared frame under idx, receive its "
     "reply and take its inputs (size 0: lost)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_exchange",
    "One cyclic frame's exchange on a raw socket, compiled (runtime/_exchange.c).", -1,
    methods,
};

PyMODINIT_FUNC PyInit__exchange(void)
{
    return PyModule_Create(&module);
}
