/* Calibration sums in one pass: per confidence bin, the pixel count, the count of correct pixels
 * and the exact sum of the confidences (as integers the Python side adds up).
 *
 * Optional speed-up of claravid/eval/inference/calibration.py, which computes the same integers
 * with numpy when this module is not built.
 *
 * Bins: a confidence's bin is looked up by the top 16 bits of its float32 pattern in a table the
 * Python side builds from the bin edges (the last edge a confidence reaches, as
 * torch.bucketize(right=True)); the few patterns whose range holds an edge, 1.0, -0.0 or the
 * limit of the fixed-point sums below are marked AMBIGUOUS and compared with the edges
 * themselves, those that can only be outside [0, 1] (NaN included) are OUTSIDE. Where the CPU
 * has AVX2 (checked at run time) and the edges are within EDGE_SLACK of j / bins (linspace
 * edges are), eight pixels at a time take the bin as the whole part of x · bins: the float32
 * product is off by under 1e-6 of a bin, so that is the table's bin unless x · bins is within
 * NEAR of a whole number. A group holding such a pixel, or one the pass cannot take otherwise
 * (a confidence outside [0, 1], below 2^-7, or -0.0; ignored pixels aside), goes through the
 * table. Both give the same bins for every float32 in [0, 1] (checked exhaustively for several
 * bin counts when this was written).
 *
 * Sums: a confidence x >= 2^-7 is a multiple of 2^-30, so x · 2^30 is an integer below 2^31 and
 * their sum is exact in int64; smaller ones (0, or a class count past 128) add their 24-bit
 * significands per binary exponent, exact too. Each pixel adds count and fixed-point value in
 * one 64-bit counter of its (lane, bin, correct) slot (count from bit 48 up), pixel i in lane
 * i % LANES so that neighbours of one bin do not wait on each other; the counters are emptied
 * every CHUNK pixels, before either part can overflow. Exact integers do not depend on the
 * order of the pixels: the numpy fallback gets the same ones, and so the same float64 sums. The
 * GIL is released while counting.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#if defined(__GNUC__) && defined(__x86_64__) && !defined(CLARAVID_NO_AVX2) /* a build may opt out */
#include <immintrin.h>
#define HAVE_AVX2_PATH 1
#endif

#define IGNORE 255
#define LANES 8
#define AMBIGUOUS 254
#define OUTSIDE 255
#define CHUNK 8192 /* per lane slot: count < 2^11, fixed-point sum < 2^41 */
#define COUNT_SHIFT 48
#define FIXED_SCALE 1073741824.0f /* 2^30 */
#define SMALL_BITS 0x3C000000u    /* the pattern of 2^-7: below it, x · 2^30 is not whole */
#define EXPONENTS 256
#define NEAR 1e-4f        /* of a bin: x · bins this near a whole number goes through the table */
#define EDGE_SLACK 1e-6   /* of a bin: how far an edge may be from j / bins (linspace: ~1e-7) */

typedef struct {
    const float *c, *e;
    const uint32_t *bits;
    const uint8_t *p, *t, *bin_of;
    Py_ssize_t bins, slots;
    uint64_t *lane;  /* [LANES][slots]: count << 48 | fixed-point sum */
    int64_t *small;  /* [bins][EXPONENTS]: significand sums of x < 2^-7 */
    int64_t *cnt, *ok, *fixed;
} Pass;

/* One pixel through the table; returns 0, or -1 for a confidence outside [0, 1]. The pass's
 * fields come as arguments: read once by the caller, not again after each counter store. */
static inline int one_pixel(const float *c, const uint32_t *bits, const uint8_t *p,
                            const uint8_t *t, const uint8_t *bin_of, const float *e,
                            Py_ssize_t bins, uint64_t *lane, int64_t *small, Py_ssize_t i) {
    const uint8_t truth = t[i];
    if (truth == IGNORE) return 0;
    const uint32_t b = bits[i];
    const float x = c[i];
    Py_ssize_t k = bin_of[b >> 16];
    if (k >= AMBIGUOUS) {
        if (k == OUTSIDE || !(x >= 0.0f && x <= 1.0f)) return -1; /* NaN too */
        for (k = 0; k < bins - 1 && x >= e[k + 1]; k++) {
        }
    }
    uint64_t add = (uint64_t)1 << COUNT_SHIFT;
    if (b < SMALL_BITS) { /* +0, subnormals and x < 2^-7: significand at its exponent */
        const uint32_t exponent = b >> 23, significand = b & 0x7FFFFF;
        small[k * EXPONENTS + (exponent ? exponent : 1)] +=
            exponent ? significand | 0x800000 : significand;
    } else {
        add += (uint64_t)(int64_t)(x * FIXED_SCALE); /* below 2^31; -0.0 adds 0 */
    }
    lane[2 * k + (p[i] == truth)] += add;
    return 0;
}

/* The pixels of [i, end) one by one (pixel i in lane i % LANES); returns the first bad one or
 * -1. */
static Py_ssize_t table_span(const Pass *s, Py_ssize_t i, Py_ssize_t end) {
    const float *c = s->c, *e = s->e;
    const uint32_t *bits = s->bits;
    const uint8_t *p = s->p, *t = s->t, *bin_of = s->bin_of;
    const Py_ssize_t bins = s->bins, slots = s->slots;
    uint64_t *lane = s->lane;
    int64_t *small = s->small;
    int j = (int)(i % LANES);
    uint64_t *mine = lane + j * slots;
    for (; i < end; i++) {
        if (one_pixel(c, bits, p, t, bin_of, e, bins, mine, small, i)) return i;
        mine += slots;
        if (++j == LANES) {
            j = 0;
            mine = lane;
        }
    }
    return -1;
}

/* Empty the lane counters into the per-bin totals. */
static void flush(Pass *s) {
    for (Py_ssize_t k = 0; k < s->bins; k++) {
        for (int ok = 0; ok < 2; ok++) {
            for (int lane = 0; lane < LANES; lane++) {
                uint64_t *slot = &s->lane[lane * s->slots + 2 * k + ok];
                const int64_t n = (int64_t)(*slot >> COUNT_SHIFT);
                s->cnt[k] += n;
                if (ok) s->ok[k] += n;
                s->fixed[k] += (int64_t)(*slot & (((uint64_t)1 << COUNT_SHIFT) - 1));
                *slot = 0;
            }
        }
    }
    for (int lane = 0; lane < LANES; lane++) s->lane[lane * s->slots + 2 * s->bins] = 0; /* spare */
}

#ifdef HAVE_AVX2_PATH
/* What the eight-pixel pass keeps in registers (read once: stores to the counters could
 * otherwise alias the pass's fields). */
typedef struct {
    const float *c;
    const uint8_t *t, *p;
    uint64_t *lane;
    __m256 bins, near_low, near_high;
    __m256i last, spare, offsets;
} Group;

/* Eight pixels from i; returns 0 when done, 1 when one of them needs the table. */
__attribute__((target("avx2"))) static inline int avx2_group(const Group *g, Py_ssize_t i) {
    const __m256 x = _mm256_loadu_ps(g->c + i);
    const __m256i truth = _mm256_cvtepu8_epi32(_mm_loadl_epi64((const __m128i *)(g->t + i)));
    const __m256i pred = _mm256_cvtepu8_epi32(_mm_loadl_epi64((const __m128i *)(g->p + i)));
    const __m256i ignored = _mm256_cmpeq_epi32(truth, _mm256_set1_epi32(IGNORE));
    /* x · bins and its whole part: the bin, unless within NEAR of a whole number (of an edge;
     * 1.0 is not: it belongs to the last bin). */
    const __m256 scaled = _mm256_mul_ps(x, g->bins);
    const __m256i whole = _mm256_cvttps_epi32(scaled);
    const __m256 part = _mm256_sub_ps(scaled, _mm256_cvtepi32_ps(whole));
    const __m256 near = _mm256_and_ps(_mm256_or_ps(_mm256_cmp_ps(part, g->near_low, _CMP_LT_OQ),
                                                   _mm256_cmp_ps(part, g->near_high, _CMP_GT_OQ)),
                                      _mm256_cmp_ps(x, _mm256_set1_ps(1.0f), _CMP_LT_OQ));
    /* Taken here: ignored, or a pattern in [2^-7, 1] (as signed integers: -0.0 and NaN fail)
     * not near an edge. */
    const __m256i pattern = _mm256_castps_si256(x);
    const __m256i low = _mm256_cmpgt_epi32(_mm256_set1_epi32((int)SMALL_BITS), pattern);
    const __m256i high = _mm256_cmpgt_epi32(pattern, _mm256_set1_epi32(0x3F800000));
    const __m256i other = _mm256_andnot_si256(
        ignored, _mm256_or_si256(_mm256_or_si256(low, high), _mm256_castps_si256(near)));
    if (!_mm256_testz_si256(other, other)) return 1;
    const __m256i k = _mm256_min_epi32(whole, g->last);
    /* Slot lane · slots + 2k + correct; ignored pixels to the spare slot past the bins. */
    __m256i slot = _mm256_sub_epi32(_mm256_add_epi32(k, k), _mm256_cmpeq_epi32(truth, pred));
    slot = _mm256_add_epi32(_mm256_blendv_epi8(slot, g->spare, ignored), g->offsets);
    /* count << 48 | x · 2^30, in 64-bit lanes. */
    const __m256i fixed = _mm256_cvttps_epi32(_mm256_mul_ps(x, _mm256_set1_ps(FIXED_SCALE)));
    const __m256i one = _mm256_set1_epi64x((int64_t)1 << COUNT_SHIFT);
    const __m256i add_lo =
        _mm256_add_epi64(_mm256_cvtepu32_epi64(_mm256_castsi256_si128(fixed)), one);
    const __m256i add_hi =
        _mm256_add_epi64(_mm256_cvtepu32_epi64(_mm256_extracti128_si256(fixed, 1)), one);
    int32_t where[8];
    uint64_t add[8];
    _mm256_storeu_si256((__m256i *)where, slot);
    _mm256_storeu_si256((__m256i *)add, add_lo);
    _mm256_storeu_si256((__m256i *)(add + 4), add_hi);
    /* Read back from memory (the empty asm may have changed them): eight scalar loads cost
     * less than the eight lane extractions the compiler would make of the registers. */
    __asm__("" : "+m"(where), "+m"(add));
    uint64_t *lane = g->lane;
    for (int j = 0; j < LANES; j++) lane[where[j]] += add[j];
    return 0;
}

/* The pixels of [i, end) in groups of eight; returns the first bad pixel, or -1. */
__attribute__((target("avx2"))) static Py_ssize_t avx2_span(Pass *s, Py_ssize_t i, Py_ssize_t end) {
    Group g;
    g.c = s->c;
    g.t = s->t;
    g.p = s->p;
    g.lane = s->lane;
    g.bins = _mm256_set1_ps((float)s->bins);
    g.near_low = _mm256_set1_ps(NEAR);
    g.near_high = _mm256_set1_ps(1.0f - NEAR);
    g.last = _mm256_set1_epi32((int)s->bins - 1);
    g.spare = _mm256_set1_epi32((int)(2 * s->bins));
    g.offsets = _mm256_mullo_epi32(_mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
                                   _mm256_set1_epi32((int)s->slots));
    for (; i + LANES <= end; i += LANES) {
        _mm_prefetch((const char *)(g.c + i) + 2048, _MM_HINT_T0);
        if ((i & 63) == 0) {
            _mm_prefetch((const char *)(g.t + i) + 1024, _MM_HINT_T0);
            _mm_prefetch((const char *)(g.p + i) + 1024, _MM_HINT_T0);
        }
        if (avx2_group(&g, i)) {
            const Py_ssize_t bad = table_span(s, i, i + LANES);
            if (bad >= 0) return bad;
        }
    }
    return -1;
}

/* Whether the edges are within EDGE_SLACK of j / bins, as the eight-pixel pass assumes. */
static int edges_even(const Pass *s) {
    for (Py_ssize_t j = 0; j <= s->bins; j++) {
        const double gap = (double)s->e[j] * (double)s->bins - (double)j;
        if (gap > EDGE_SLACK || gap < -EDGE_SLACK) return 0;
    }
    return 1;
}
#endif

static PyObject *exact_sums(PyObject *self, PyObject *args) {
    Py_buffer conf, pred, truth, edges, lut, count, correct, fixed, small;
    int vector = 1;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*w*w*w*w*|p", &conf, &pred, &truth, &edges, &lut,
                          &count, &correct, &fixed, &small, &vector))
        return NULL;
    PyObject *result = NULL;
    const Py_ssize_t n = truth.len, bins = edges.len / 4 - 1;
    if (conf.len != 4 * n || pred.len != n) {
        PyErr_SetString(PyExc_ValueError, "conf (float32), pred and truth (uint8) must match");
    } else if (bins < 1 || bins >= AMBIGUOUS || count.len != 8 * bins ||
               correct.len != 8 * bins || fixed.len != 8 * bins ||
               small.len != 8 * bins * EXPONENTS || lut.len != 65536) {
        PyErr_SetString(PyExc_ValueError,
                        "edges must hold bins + 1 float32, lut 65536 bytes, count, correct and "
                        "fixed bins int64, small bins * 256 int64");
    } else {
        Pass s = {conf.buf, edges.buf, conf.buf, pred.buf, truth.buf, lut.buf, bins,
                  2 * bins + 1, NULL, small.buf, count.buf, correct.buf, fixed.buf};
        s.lane = calloc((size_t)(LANES * s.slots), sizeof(uint64_t));
        if (s.lane == NULL) {
            PyErr_NoMemory();
        } else {
            Py_ssize_t bad = -1;
#ifdef HAVE_AVX2_PATH
            const int use_avx2 = vector && __builtin_cpu_supports("avx2") && edges_even(&s);
#else
            (void)vector;
#endif
            Py_BEGIN_ALLOW_THREADS
            for (Py_ssize_t start = 0; start < n && bad < 0; start += CHUNK) {
                const Py_ssize_t end = n - start < CHUNK ? n : start + CHUNK;
                Py_ssize_t i = start;
#ifdef HAVE_AVX2_PATH
                if (use_avx2) {
                    bad = avx2_span(&s, i, end);
                    i = start + (end - start) / LANES * LANES;
                }
#endif
                if (bad < 0) bad = table_span(&s, i, end);
                flush(&s);
            }
            Py_END_ALLOW_THREADS
            free(s.lane);
            if (bad >= 0) {
                PyObject *value = PyFloat_FromDouble((double)s.c[bad]);
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
    }
    PyBuffer_Release(&conf);
    PyBuffer_Release(&pred);
    PyBuffer_Release(&truth);
    PyBuffer_Release(&edges);
    PyBuffer_Release(&lut);
    PyBuffer_Release(&count);
    PyBuffer_Release(&correct);
    PyBuffer_Release(&fixed);
    PyBuffer_Release(&small);
    return result;
}

static PyMethodDef methods[] = {
    {"exact_sums", exact_sums, METH_VARARGS,
     "exact_sums(conf, pred, truth, edges, lut, count, correct, fixed, small, vector=True): add "
     "one image's pixels (in place)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_calibration", NULL, -1, methods};

PyMODINIT_FUNC PyInit__calibration(void) { return PyModule_Create(&module); }
