/* Calibration sums in one pass: per confidence bin, the pixel count, the sum of confidences and
 * the count of correct pixels.
 *
 * Optional speed-up of claravid/eval/inference/calibration.py, which computes the same numbers
 * with numpy when this module is not built. A confidence's bin is looked up by the top 16 bits of
 * its float32 pattern in a table the Python side builds from the bin edges (the last edge a
 * confidence reaches, as torch.bucketize(right=True)); the few patterns whose range holds an
 * edge, 1.0 or -0.0 are marked AMBIGUOUS and compared with the edges themselves, those that can
 * only be outside [0, 1] (NaN included) are OUTSIDE. Confidences
 * are summed in float64 in LANES interleaved partial sums (the j-th counted pixel into lane
 * j % LANES, so that pixels of one bin do not wait on each other), added up lane by lane at the
 * end; the numpy fallback sums in the same order, so the two agree to the bit. The GIL is
 * released while counting.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <stdlib.h>

#define IGNORE 255
#define LANES 4
#define AMBIGUOUS 254
#define OUTSIDE 255

static PyObject *sums(PyObject *self, PyObject *args) {
    Py_buffer conf, pred, truth, edges, lut, count, conf_sum, correct;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*w*w*w*", &conf, &pred, &truth, &edges, &lut, &count,
                          &conf_sum, &correct))
        return NULL;
    PyObject *result = NULL;
    const Py_ssize_t n = truth.len, bins = edges.len / 4 - 1;
    if (conf.len != 4 * n || pred.len != n) {
        PyErr_SetString(PyExc_ValueError, "conf (float32), pred and truth (uint8) must match");
    } else if (bins < 1 || bins >= AMBIGUOUS || count.len != 8 * bins ||
               conf_sum.len != 8 * bins || correct.len != 8 * bins || lut.len != 65536) {
        PyErr_SetString(PyExc_ValueError,
                        "edges must hold bins + 1 float32, lut 65536 bytes, outputs bins 8-byte");
    } else {
        const float *c = conf.buf, *e = edges.buf;
        const uint32_t *bits = conf.buf;
        const uint8_t *p = pred.buf, *t = truth.buf, *bin_of = lut.buf;
        int64_t *cnt = count.buf, *ok = correct.buf;
        double *sum = conf_sum.buf;
        double *lane_sum = calloc((size_t)(LANES * bins), sizeof(double));
        int64_t *lane_cnt = calloc((size_t)(LANES * bins), sizeof(int64_t));
        int64_t *lane_ok = calloc((size_t)(LANES * bins), sizeof(int64_t));
        Py_ssize_t bad = -1;
        if (lane_sum == NULL || lane_cnt == NULL || lane_ok == NULL) {
            free(lane_sum);
            free(lane_cnt);
            free(lane_ok);
            PyBuffer_Release(&conf);
            PyBuffer_Release(&pred);
            PyBuffer_Release(&truth);
            PyBuffer_Release(&edges);
            PyBuffer_Release(&lut);
            PyBuffer_Release(&count);
            PyBuffer_Release(&conf_sum);
            PyBuffer_Release(&correct);
            return PyErr_NoMemory();
        }
        Py_BEGIN_ALLOW_THREADS
        Py_ssize_t j = 0;
        for (Py_ssize_t i = 0; i < n; i++) {
            if (t[i] == IGNORE) continue;
            const float x = c[i];
            Py_ssize_t k = bin_of[bits[i] >> 16];
            if (k >= AMBIGUOUS) {
                if (k == OUTSIDE || !(x >= 0.0f && x <= 1.0f)) { /* NaN too */
                    bad = i;
                    break;
                }
                for (k = 0; k < bins - 1 && x >= e[k + 1]; k++) {
                }
            }
            const Py_ssize_t slot = (j++ % LANES) * bins + k;
            lane_cnt[slot]++;
            lane_sum[slot] += (double)x;
            lane_ok[slot] += p[i] == t[i];
        }
        for (Py_ssize_t k = 0; k < bins; k++) {
            for (int lane = 0; lane < LANES; lane++) {
                cnt[k] += lane_cnt[lane * bins + k];
                sum[k] += lane_sum[lane * bins + k];
                ok[k] += lane_ok[lane * bins + k];
            }
        }
        Py_END_ALLOW_THREADS
        free(lane_sum);
        free(lane_cnt);
        free(lane_ok);
        if (bad >= 0) {
            PyObject *value = PyFloat_FromDouble((double)c[bad]);
            if (value != NULL) {
                PyErr_Format(PyExc_ValueError, "confidence %R at pixel %zd is not in [0, 1]",
                             value, bad);
                Py_DECREF(value);
            }
        } else {
            result = Py_None;
            Py_INCREF(result);
        }
    }
    PyBuffer_Release(&conf);
    PyBuffer_Release(&pred);
    PyBuffer_Release(&truth);
    PyBuffer_Release(&edges);
    PyBuffer_Release(&lut);
    PyBuffer_Release(&count);
    PyBuffer_Release(&conf_sum);
    PyBuffer_Release(&correct);
    return result;
}

static PyMethodDef methods[] = {
    {"sums", sums, METH_VARARGS,
     "sums(conf, pred, truth, edges, lut, count, conf_sum, correct): add one image's pixels."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_calibration", NULL, -1, methods};

PyMODINIT_FUNC PyInit__calibration(void) { return PyModule_Create(&module); }
