/* Joint counts of two byte images: how many pixels hold each pair (a, b) of bytes.
 *
 * Optional speed-up of claravid/eval/inference/joint_counts.py, which counts the same pairs with
 * OpenCV's 2-D histogram (and numpy past 2^24 pixels) when this module is not built. The keyed
 * images the measures count (Boundary IoU's band keys, cross-view's kept labels) are runs of one
 * pair along a row, so the pass counts runs: it extends a run eight pixels at a time while both
 * images repeat its bytes and adds the run's length once, instead of one increment per pixel
 * that would wait on the previous one. The second image may be one channel of a two-channel
 * (interleaved) image, read in place. The counts are exact integers, as the fallback's. The GIL
 * is released while counting.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#define REPEAT8 0x0101010101010101ULL
#define REPEAT16 0x0001000100010001ULL

static PyObject *count(PyObject *self, PyObject *args) {
    Py_buffer first, second, out;
    Py_ssize_t channels = 1, channel = 0;
    if (!PyArg_ParseTuple(args, "y*y*w*|nn", &first, &second, &out, &channels, &channel))
        return NULL;
    PyObject *result = NULL;
    if ((channels != 1 && channels != 2) || channel < 0 || channel >= channels) {
        PyErr_SetString(PyExc_ValueError, "second must have 1 or 2 interleaved channels");
    } else if (second.len != channels * first.len) {
        PyErr_SetString(PyExc_ValueError, "the two byte images must hold as many pixels");
    } else if (out.len != 65536 * 8) {
        PyErr_SetString(PyExc_ValueError, "out must hold 256 * 256 int64 counts");
    } else {
        const uint8_t *a = first.buf, *b = second.buf;
        int64_t *counts = out.buf;
        const Py_ssize_t n = first.len;
        /* Eight pixels of the second image: 8 bytes, or 16 of which every other one counts. */
        const uint64_t keep = channels == 1 ? ~0ULL : (0xFF * REPEAT16) << (8 * channel);
        Py_BEGIN_ALLOW_THREADS
        Py_ssize_t i = 0;
        while (i < n) {
            const Py_ssize_t start = i;
            const uint8_t x = a[i], y = b[i * channels + channel];
            const uint64_t xs = x * REPEAT8;
            const uint64_t ys = (channels == 1 ? y * REPEAT8 : y * REPEAT16) << (8 * channel);
            i++;
            while (i + 8 <= n) {
                uint64_t u, v, w = ys;
                memcpy(&u, a + i, 8);
                memcpy(&v, b + i * channels, 8);
                if (channels == 2) memcpy(&w, b + i * 2 + 8, 8);
                if (u != xs || (v & keep) != ys || (w & keep) != ys) break;
                i += 8;
            }
            while (i < n && a[i] == x && b[i * channels + channel] == y) i++;
            counts[(x << 8) | y] += i - start;
        }
        Py_END_ALLOW_THREADS
        result = Py_None;
        Py_INCREF(result);
    }
    PyBuffer_Release(&first);
    PyBuffer_Release(&second);
    PyBuffer_Release(&out);
    return result;
}

static PyMethodDef methods[] = {
    {"count", count, METH_VARARGS,
     "count(first, second, out, channels=1, channel=0): add the joint counts of two byte images "
     "to out (int64 [65536], index first << 8 | second); second may interleave two channels."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_joint_counts", NULL, -1, methods};

PyMODINIT_FUNC PyInit__joint_counts(void) { return PyModule_Create(&module); }
