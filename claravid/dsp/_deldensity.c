/* The deldensity histogram in one pass: (gx, gy) int16 gradient pairs -> 512 x 512 uint32 counts.
 *
 * Optional speed-up of claravid/dsp/metrics.py (which falls back to OpenCV + numpy when this
 * module is not built). Bins come from a look-up table over every int16 value, built in Python
 * from numpy's own histogram2d edges, so the counts are identical; this file only counts, with
 * no branch in the loop. The GIL is released while counting.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

#define LUT_SIZE 65536     /* one bin per int16 value, indexed by its uint16 bit pattern */
#define SIDE 512           /* 511 bins + 1 drop bin per axis */

static PyObject *count(PyObject *self, PyObject *args) {
    Py_buffer gx, gy, lut, out;
    if (!PyArg_ParseTuple(args, "y*y*y*w*", &gx, &gy, &lut, &out)) return NULL;
    PyObject *result = NULL;
    if (gx.len != gy.len || gx.len % 2) {
        PyErr_SetString(PyExc_ValueError, "gx and gy must be int16 buffers of equal length");
    } else if (gx.len / 2 > (Py_ssize_t)UINT32_MAX) {
        PyErr_SetString(PyExc_ValueError, "more than 2**32 pixels: count in row blocks");
    } else if (lut.len != LUT_SIZE * 2) {
        PyErr_SetString(PyExc_ValueError, "lut must hold 65536 uint16 bins (< 512)");
    } else if (out.len != SIDE * SIDE * 4) {
        PyErr_SetString(PyExc_ValueError, "out must be a 512 x 512 uint32 buffer");
    } else {
        const uint16_t *x = gx.buf, *y = gy.buf, *bins = lut.buf;
        uint32_t *hist = out.buf;
        const Py_ssize_t n = gx.len / 2;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < n; i++) {
            hist[((bins[x[i]] & (SIDE - 1)) << 9) | (bins[y[i]] & (SIDE - 1))]++;
        }
        Py_END_ALLOW_THREADS
        result = Py_None;
        Py_INCREF(result);
    }
    PyBuffer_Release(&gx);
    PyBuffer_Release(&gy);
    PyBuffer_Release(&lut);
    PyBuffer_Release(&out);
    return result;
}

static PyMethodDef methods[] = {
    {"count", count, METH_VARARGS,
     "count(gx, gy, lut, out): add the (lut[gx], lut[gy]) pairs into out (512 x 512 uint32)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_deldensity", NULL, -1, methods};

PyMODINIT_FUNC PyInit__deldensity(void) { return PyModule_Create(&module); }
