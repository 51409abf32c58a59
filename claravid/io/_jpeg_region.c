/* Decode one window of a JPEG with libjpeg(-turbo), pixel for pixel as a full decode gives it.
 *
 * Optional speed-up of claravid/io/jpeg_region.py, which falls back to a full OpenCV decode and a
 * slice when this module is not built. A training crop needs about a thirtieth of a 12 MP frame:
 * the entropy-coded data must still be read in order, but the inverse DCT, chroma upsampling and
 * colour conversion are done only for the MCU columns (jpeg_crop_scanline) and rows
 * (jpeg_skip_scanlines, stopping after the last row) around the window.
 *
 * Same settings as OpenCV's imread (ISLOW inverse DCT, smooth "fancy" chroma upsampling, RGB
 * output), so the pixels are the same. Smooth upsampling of subsampled chroma reads neighbouring
 * chroma samples, so `margin_x` and `margin_y` iMCUs are decoded beside the window (where the
 * image has them) and cut away. What each axis needs, measured on libjpeg-turbo 2.1.5 (Debian 12)
 * over every sampling and encoder of tests/claravid/io/test_jpeg_region.py and 300 random windows
 * of a 700x530 frame each (8,205 windows):
 *   - horizontal: needed. jpeg_crop_scanline makes the crop's left and right columns image edges
 *     for the h2v1 (4:2:2) and h2v2 (4:2:0) upsamplers; without it about half of the windows of
 *     those files differ. 4:4:4, 4:1:1 (replicated, not smoothed), 4:4:0 and grey need none.
 *   - vertical: not needed on 2.1.5 (no window differs without it): jpeg_skip_scanlines decodes
 *     the row group above the first row it returns when the upsampler needs context rows, and the
 *     main controller reads one row group ahead below the last. It is kept, at the cost of one
 *     iMCU row (16 rows, ~3 % of a 630-row crop), because jpeg_skip_scanlines had several fixes
 *     up to 2.0.6 and 2.1.4 (libjpeg-turbo's ChangeLog), which older libraries lack.
 * The test test_each_margin_is_measured pins both findings (the vertical one on 2.1.x).
 *
 * Only sequential (baseline) files are read by window: claravid/io/jpeg_region.py decodes
 * progressive ones whole with OpenCV. Block smoothing of an incomplete progressive file (legal:
 * its last scans missing) reads two blocks around each block, more than the margin, and the
 * system's libjpeg-turbo 2.1 smooths differently from OpenCV's 3.x: no margin would make such a
 * window equal OpenCV's full decode. (A one-pixel window of a progressive file still serves: it
 * makes libjpeg read every scan, which refuses data that ends inside a scan.)
 *
 * libjpeg reports fatal errors through error_exit, which must not return: a custom error manager
 * jumps back (setjmp/longjmp) and the call raises a Python exception with libjpeg's message. The
 * warnings that mean "pixels were invented" (data ran out, bad Huffman code) are fatal too, where
 * libjpeg alone would fill the missing blocks with grey. The GIL is released while decoding.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <setjmp.h>
#include <stdio.h>
#include <string.h>

#include <jerror.h>
#include <jpeglib.h>

static PyObject *UnsupportedError; /* the caller decodes such files another way */

struct error_mgr {
    struct jpeg_error_mgr pub;
    jmp_buf jump;
    int unsupported;
    char message[JMSG_LENGTH_MAX];
};

static void raise_error(j_common_ptr cinfo) {
    struct error_mgr *err = (struct error_mgr *)cinfo->err;
    int code = err->pub.msg_code;
    err->unsupported = code == JERR_BAD_PRECISION || code == JERR_CONVERSION_NOTIMPL ||
                       code == JERR_NOT_COMPILED || code == JERR_SOF_UNSUPPORTED;
    (*err->pub.format_message)(cinfo, err->message);
    longjmp(err->jump, 1);
}

/* (JWRN_ARITH_BAD_CODE is not declared to clients of the libjpeg-6b API: arithmetic-coded
 * files, which hardly exist, keep libjpeg's own handling of that warning.) */
static int invents_pixels(int code) {
    return code == JWRN_JPEG_EOF || code == JWRN_HIT_MARKER || code == JWRN_HUFF_BAD_CODE ||
           code == JWRN_MUST_RESYNC;
}

static void emit_message(j_common_ptr cinfo, int level) {
    if (level < 0 && invents_pixels(cinfo->err->msg_code)) raise_error(cinfo);
    /* Other warnings (extraneous bytes, unknown JFIF revision) leave the pixels intact: as in
     * OpenCV, decoding goes on; nothing is printed from a library. */
}

static void silent(j_common_ptr cinfo) { (void)cinfo; }

struct job {
    const unsigned char *data;
    unsigned long size;
    unsigned int x, y, w, h, margin_x, margin_y;
    unsigned char *out; /* h * w * 3 bytes, RGB */
};

/* 0 on success; -1 with err->message set. Runs without the GIL: no Python calls here. */
static int decode(struct job *job, struct error_mgr *err) {
    struct jpeg_decompress_struct cinfo;
    cinfo.err = jpeg_std_error(&err->pub);
    err->pub.error_exit = raise_error;
    err->pub.emit_message = emit_message;
    err->pub.output_message = silent;
    err->unsupported = 0;
    if (setjmp(err->jump)) {
        jpeg_destroy_decompress(&cinfo);
        return -1;
    }
    jpeg_create_decompress(&cinfo);
    jpeg_mem_src(&cinfo, job->data, job->size);
    jpeg_read_header(&cinfo, TRUE);
    if (cinfo.jpeg_color_space != JCS_YCbCr && cinfo.jpeg_color_space != JCS_GRAYSCALE &&
        cinfo.jpeg_color_space != JCS_RGB) {
        snprintf(err->message, JMSG_LENGTH_MAX, "unsupported JPEG colour space %d (CMYK/YCCK?)",
                 (int)cinfo.jpeg_color_space);
        err->unsupported = 1;
        jpeg_destroy_decompress(&cinfo);
        return -1;
    }
    if ((unsigned long)job->x + job->w > cinfo.image_width ||
        (unsigned long)job->y + job->h > cinfo.image_height || job->w == 0 || job->h == 0) {
        snprintf(err->message, JMSG_LENGTH_MAX, "window %ux%u at (%u, %u) outside the %ux%u image",
                 job->w, job->h, job->x, job->y, cinfo.image_width, cinfo.image_height);
        jpeg_destroy_decompress(&cinfo);
        return -1;
    }
    cinfo.out_color_space = JCS_EXT_RGB; /* grey files come out as three equal channels */
    cinfo.dct_method = JDCT_ISLOW;
    cinfo.do_fancy_upsampling = TRUE;
    jpeg_start_decompress(&cinfo);

    /* The decoded region: the window plus `margin` iMCUs on each side, clipped to the image. */
    unsigned long mw = (unsigned long)job->margin_x * cinfo.max_h_samp_factor * DCTSIZE;
    unsigned long mh = (unsigned long)job->margin_y * cinfo.max_v_samp_factor * DCTSIZE;
    unsigned long x0 = job->x > mw ? job->x - mw : 0;
    unsigned long x1 = job->x + job->w + mw;
    unsigned long y0 = job->y > mh ? job->y - mh : 0;
    unsigned long y1 = job->y + job->h + mh;
    if (x1 > cinfo.output_width) x1 = cinfo.output_width;
    if (y1 > cinfo.output_height) y1 = cinfo.output_height;

    JDIMENSION xoffset = (JDIMENSION)x0, width = (JDIMENSION)(x1 - x0);
    jpeg_crop_scanline(&cinfo, &xoffset, &width); /* xoffset moves down to an iMCU edge */
    if (y0 > 0) jpeg_skip_scanlines(&cinfo, (JDIMENSION)y0);
    JSAMPARRAY row = (*cinfo.mem->alloc_sarray)((j_common_ptr)&cinfo, JPOOL_IMAGE,
                                                width * cinfo.output_components, 1);
    const size_t skip = (size_t)(job->x - xoffset) * 3, line = (size_t)job->w * 3;
    while (cinfo.output_scanline < y1) {
        JDIMENSION r = cinfo.output_scanline;
        if (jpeg_read_scanlines(&cinfo, row, 1) != 1) {
            snprintf(err->message, JMSG_LENGTH_MAX, "libjpeg returned no row %u", r);
            jpeg_destroy_decompress(&cinfo);
            return -1;
        }
        if (r >= job->y && r < job->y + job->h) {
            memcpy(job->out + (size_t)(r - job->y) * line, row[0] + skip, line);
        }
    }
    /* The rows below the region are never decoded: abort instead of finishing. */
    jpeg_abort_decompress(&cinfo);
    jpeg_destroy_decompress(&cinfo);
    return 0;
}

/* A coordinate or size argument as a C integer in [low, JPEG_MAX_DIMENSION]: a Python int of
 * any size is checked here, never wrapped (the `I` format would read 2**32 + 5 as 5). */
static int dimension(PyObject *value, const char *name, long low, unsigned int *out) {
    if (!PyLong_Check(value)) {
        PyErr_Format(PyExc_TypeError, "%s must be an integer, got %.100s", name,
                     Py_TYPE(value)->tp_name);
        return -1;
    }
    int overflow = 0;
    long long v = PyLong_AsLongLongAndOverflow(value, &overflow);
    if (v == -1 && PyErr_Occurred()) return -1;
    if (overflow != 0 || v < low || v > JPEG_MAX_DIMENSION) {
        PyObject *text = PyObject_Repr(value);
        if (text != NULL) {
            PyErr_Format(PyExc_ValueError, "%s = %U is out of range: need %ld <= %s <= %d", name,
                         text, low, name, (int)JPEG_MAX_DIMENSION);
            Py_DECREF(text);
        }
        return -1;
    }
    *out = (unsigned int)v;
    return 0;
}

/* `out` must be exactly what the caller gets back: uint8, C-contiguous, shape (h, w, 3). A float
 * array or a flat byte buffer of the right length would be filled with bytes that mean nothing. */
static int check_out(const Py_buffer *out, unsigned int w, unsigned int h) {
    const char *format = out->format == NULL ? "B" : out->format;
    if (strcmp(format, "B") != 0 || out->itemsize != 1) {
        PyErr_Format(PyExc_TypeError, "out must be a uint8 array, got format '%s'", format);
        return -1;
    }
    if (out->ndim != 3 || out->shape[0] != (Py_ssize_t)h || out->shape[1] != (Py_ssize_t)w ||
        out->shape[2] != 3) {
        PyErr_Format(PyExc_ValueError,
                     "out must have the shape (h, w, 3) = (%u, %u, 3), got %d dimension(s)", h, w,
                     out->ndim);
        return -1;
    }
    return 0;
}

static PyObject *decode_window(PyObject *self, PyObject *args, PyObject *kwargs) {
    (void)self;
    static char *keywords[] = {"data", "x", "y", "w", "h", "out", "margin_x", "margin_y", NULL};
    Py_buffer data;
    PyObject *ox, *oy, *ow, *oh, *oout, *omx = NULL, *omy = NULL;
    unsigned int x, y, w, h, margin_x = 1, margin_y = 1;
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "y*OOOOO|OO", keywords, &data, &ox, &oy, &ow,
                                     &oh, &oout, &omx, &omy))
        return NULL;
    PyObject *result = NULL;
    Py_buffer out;
    out.obj = NULL;
    if (dimension(ox, "x", 0, &x) < 0 || dimension(oy, "y", 0, &y) < 0 ||
        dimension(ow, "w", 1, &w) < 0 || dimension(oh, "h", 1, &h) < 0 ||
        (omx != NULL && dimension(omx, "margin_x", 0, &margin_x) < 0) ||
        (omy != NULL && dimension(omy, "margin_y", 0, &margin_y) < 0))
        goto done;
    /* Writable, C-contiguous (the exporter refuses otherwise), with its format and shape. */
    if (PyObject_GetBuffer(oout, &out, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        out.obj = NULL;
        goto done;
    }
    if (check_out(&out, w, h) < 0) goto done;
    {
        struct job job = {data.buf, (unsigned long)data.len, x, y, w, h, margin_x, margin_y,
                          out.buf};
        struct error_mgr err;
        int status;
        Py_BEGIN_ALLOW_THREADS
        status = decode(&job, &err);
        Py_END_ALLOW_THREADS
        if (status == 0) {
            result = Py_None;
            Py_INCREF(result);
        } else {
            PyErr_SetString(err.unsupported ? UnsupportedError : PyExc_ValueError, err.message);
        }
    }
done:
    PyBuffer_Release(&data);
    if (out.obj != NULL) PyBuffer_Release(&out);
    return result;
}

static PyMethodDef methods[] = {
    {"decode_window", (PyCFunction)(void (*)(void))decode_window, METH_VARARGS | METH_KEYWORDS,
     "decode_window(data, x, y, w, h, out, margin_x=1, margin_y=1): decode the w x h window at "
     "(x, y) of the JPEG bytes `data` into `out` (a uint8 C-contiguous array of shape (h, w, 3), "
     "RGB). TypeError for arguments of the wrong type; ValueError for a window outside the image "
     "or corrupt data; UnsupportedError for CMYK, 12-bit, lossless and similar files."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_jpeg_region", NULL, -1, methods};

PyMODINIT_FUNC PyInit__jpeg_region(void) {
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    UnsupportedError = PyErr_NewException("claravid._jpeg_region.UnsupportedError",
                                          PyExc_ValueError, NULL);
#ifdef LIBJPEG_TURBO_VERSION_NUMBER
    const long version = LIBJPEG_TURBO_VERSION_NUMBER; /* 2001005 for 2.1.5 */
#else
    const long version = 0; /* not libjpeg-turbo */
#endif
    if (UnsupportedError == NULL ||
        PyModule_AddObjectRef(m, "UnsupportedError", UnsupportedError) < 0 ||
        PyModule_AddIntConstant(m, "LIBJPEG_TURBO_VERSION", version) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
