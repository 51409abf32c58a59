/* Joint counts of two byte images: how many pixels hold each pair (a, b) of bytes.
 *
 * Optional speed-up of claravid/eval/inference/joint_counts.py, which counts the same pairs with
 * OpenCV's 2-D histogram (and numpy past 2^24 pixels) when this module is not built. The keyed
 * images the measures count (Boundary IoU's band keys, cross-view's kept labels) are runs of one
 * pair along a row, so the pass counts runs: it extends a run eight pixels at a time while both
 * images repeat its bytes and adds the run's length once, instead of one increment per pixel
 * that would wait on the previous one. The counts are exact integers, as the fallback's. The GIL
 * is released while counting.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#define REPEAT8 0x0101010101010101ULL

static PyObject *count(PyObject *self, PyObject *args) {
    Py_buffer first, second, out;
    if (!PyArg_ParseTuple(args, "y*y*w*", &first, &second, &out)) return NULL;
    PyObject *result = NULL;
    if (first.len != second.len) {
        PyErr_SetString(PyExc_ValueError, "the two byte images must hold as many bytes");
    } else if (out.len != 65536 * 8) {
        PyErr_SetString(PyExc_ValueError, "out must hold 256 * 256 int64 counts");
    } else {
        const uint8_t *a = first.buf, *b = second.buf;
        int64_t *counts = out.buf;
        const Py_ssize_t n = first.len;
        Py_BEGIN_ALLOW_THREADS
        Py_ssize_t i = 0;
        while (i < n) {
            const Py_ssize_t start = i;
            const uint8_t x = a[i], y = b[i];
            const uint64_t xs = x * REPEAT8, ys = y * REPEAT8;
            i++;
            while (i + 8 <= n) {
                uint64_t u, v;
                memcpy(&u, a + i, 8);
                memcpy(&v, b + i, 8);
                if (u != xs || v != ys) break;
                i += 8;
            }
            while (i < n && a[i] == x && b[i] == y) i++;
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
     "count(first, second, out): add the joint counts of two byte images to out (int64 [65536], "
     "index first << 8 | second)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_joint_counts", NULL, -1, methods};

PyMODINIT_FUNC PyInit__joint_counts(void) { return PyModule_Create(&module); }
