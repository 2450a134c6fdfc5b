/* Hot loops of jsar.features, compiled because numpy cannot reach the per-frame budget (see
 * jsar/features/bench.py). Each function mirrors a documented numpy reference in the Python
 * modules (patches.resample_regions_reference, fhog.fhog_batch_reference, colour attributes) and
 * the tests check that they agree. Arguments are C-contiguous buffers (numpy arrays) plus their
 * sizes; the Python wrappers validate dtypes and shapes, this file re-checks buffer sizes and
 * index ranges so that a wrong call raises instead of reading out of bounds.
 * Plain C99 on the CPython buffer protocol: no numpy headers are needed to build it.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#if defined(__aarch64__)
#include <arm_neon.h>
#endif

/* On x86-64 with GCC >= 11 and glibc, the two hot loops are compiled twice, for AVX2/FMA
 * (x86-64-v3) and for the baseline, and the loader picks one per CPU (ifunc): ~1.5x faster on
 * AVX2 machines, still runs on any x86-64. Results of the two versions differ only by float
 * rounding (FMA contraction). Elsewhere (ARM, clang, musl) the baseline build is used. */
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 11 && defined(__x86_64__) && defined(__GLIBC__)
#define HOT_LOOP_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define HOT_LOOP_CLONES
#endif
/* Unroll a short vectorised loop four times: its counter and branch were 3 of the 7 instructions an iteration on
 * aarch64 (rows of 72 floats). The same operations in the same order. */
#if defined(__GNUC__) && !defined(__clang__)
#define UNROLL4 _Pragma("GCC unroll 4")
#else
#define UNROLL4
#endif

/* Helpers of a cloned hot loop must be inlined into it to be compiled for its target. */
#if defined(__GNUC__)
#define ALWAYS_INLINE inline __attribute__((always_inline))
#else
#define ALWAYS_INLINE inline
#endif

static int host_is_little_endian(void)
{
    const uint16_t one = 1;
    return *(const uint8_t *)&one == 1;
}

/* A C-contiguous buffer of at least `need` bytes; with `code` ("f": float32, "Zf": complex64; NULL: any) its
 * items must be of that type. A wrong item type is a TypeError, too few bytes a ValueError, both naming the
 * argument. */
static int get_buffer_of(PyObject *obj, Py_buffer *view, int writable, Py_ssize_t need, const char *code,
                         const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0)
        return -1;
    if (code) {
        const char *fmt = view->format ? view->format : "B";
        if (fmt[0] == '@' || fmt[0] == '=' || (fmt[0] == '<' && host_is_little_endian()))
            fmt++;
        if (strcmp(fmt, code) != 0 || view->itemsize != (code[0] == 'Z' ? 8 : 4)) {
            PyErr_Format(PyExc_TypeError, "%s: expected %s items, got format '%s'", name,
                         code[0] == 'Z' ? "complex64" : "float32", view->format ? view->format : "B");
            PyBuffer_Release(view);
            return -1;
        }
    }
    if (view->len < need) {
        PyErr_Format(PyExc_ValueError, "%s: buffer holds %zd bytes, %zd needed", name, view->len, need);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

static int get_buffer(PyObject *obj, Py_buffer *view, int writable, Py_ssize_t need, const char *name)
{
    return get_buffer_of(obj, view, writable, need, NULL, name);
}

/* ---------------------------------------------------------------------------------------------
 * Resampling weights along one axis (the specification is patches.axis_weights): sample j of the
 * region [start, start + size) has footprint centred at start + (j + 0.5) * step, width
 * max(step, 1), step = size / n_out; pixel q covers [q, q + 1), pixel 0 also everything left of
 * the image and pixel n_src - 1 everything right of it (border replication).
 * Output: first[j], count[j] and weight[j * max_taps + t] for pixels first[j] + t.
 */
typedef struct {
    Py_ssize_t n_out, max_taps;
    Py_ssize_t *first, *count;
    float *weight;
} AxisTaps;

static void axis_taps_free(AxisTaps *a)
{
    free(a->first);
    free(a->count);
    free(a->weight);
    a->first = a->count = NULL;
    a->weight = NULL;
}

HOT_LOOP_CLONES
static int axis_taps(double start, double size, Py_ssize_t n_out, Py_ssize_t n_src, AxisTaps *a)
{
    const double step = size / (double)n_out;
    const double width = step > 1.0 ? step : 1.0;
    a->n_out = n_out;
    a->first = (Py_ssize_t *)malloc(sizeof(Py_ssize_t) * (size_t)n_out);
    a->count = (Py_ssize_t *)malloc(sizeof(Py_ssize_t) * (size_t)n_out);
    a->weight = NULL;
    if (!a->first || !a->count) {
        axis_taps_free(a);
        return -1;
    }
    a->max_taps = 1;
    for (Py_ssize_t j = 0; j < n_out; j++) {
        const double lo = start + ((double)j + 0.5) * step - 0.5 * width;
        const double hi = lo + width;
        double f = floor(lo), l = ceil(hi) - 1.0;
        f = f < 0.0 ? 0.0 : (f > (double)(n_src - 1) ? (double)(n_src - 1) : f);
        l = l < 0.0 ? 0.0 : (l > (double)(n_src - 1) ? (double)(n_src - 1) : l);
        a->first[j] = (Py_ssize_t)f;
        a->count[j] = (Py_ssize_t)l - (Py_ssize_t)f + 1;
        if (a->count[j] > a->max_taps)
            a->max_taps = a->count[j];
    }
    a->weight = (float *)calloc((size_t)(n_out * a->max_taps), sizeof(float)); /* unused taps: weight 0 */
    if (!a->weight) {
        axis_taps_free(a);
        return -1;
    }
    for (Py_ssize_t j = 0; j < n_out; j++) {
        const double lo = start + ((double)j + 0.5) * step - 0.5 * width;
        const double hi = lo + width;
        for (Py_ssize_t t = 0; t < a->count[j]; t++) {
            const Py_ssize_t q = a->first[j] + t;
            const double cell_lo = q <= 0 ? -INFINITY : (double)q;
            const double cell_hi = q >= n_src - 1 ? INFINITY : (double)q + 1.0;
            const double overlap = (hi < cell_hi ? hi : cell_hi) - (lo > cell_lo ? lo : cell_lo);
            a->weight[j * a->max_taps + t] = (float)((overlap > 0.0 ? overlap : 0.0) / width);
        }
    }
    return 0;
}

/* axis_taps into buffers kept across regions (no allocation per region): first and count hold n_out entries,
 * the weights grow when a region needs more (*capacity floats). The same arithmetic as axis_taps. */
HOT_LOOP_CLONES
static int axis_taps_reusing(double start, double size, Py_ssize_t n_out, Py_ssize_t n_src, AxisTaps *a,
                             Py_ssize_t *capacity)
{
    const double step = size / (double)n_out;
    const double width = step > 1.0 ? step : 1.0;
    a->n_out = n_out;
    a->max_taps = 1;
    for (Py_ssize_t j = 0; j < n_out; j++) {
        const double lo = start + ((double)j + 0.5) * step - 0.5 * width;
        const double hi = lo + width;
        double f = floor(lo), l = ceil(hi) - 1.0;
        f = f < 0.0 ? 0.0 : (f > (double)(n_src - 1) ? (double)(n_src - 1) : f);
        l = l < 0.0 ? 0.0 : (l > (double)(n_src - 1) ? (double)(n_src - 1) : l);
        a->first[j] = (Py_ssize_t)f;
        a->count[j] = (Py_ssize_t)l - (Py_ssize_t)f + 1;
        if (a->count[j] > a->max_taps)
            a->max_taps = a->count[j];
    }
    if (n_out * a->max_taps > *capacity) {
        float *grown = (float *)realloc(a->weight, sizeof(float) * (size_t)(n_out * a->max_taps));
        if (!grown)
            return -1;
        a->weight = grown;
        *capacity = n_out * a->max_taps;
    }
    for (Py_ssize_t t = 0; t < n_out * a->max_taps; t++)
        a->weight[t] = 0.0f; /* unused taps: weight 0 */
    for (Py_ssize_t j = 0; j < n_out; j++) {
        const double lo = start + ((double)j + 0.5) * step - 0.5 * width;
        const double hi = lo + width;
        for (Py_ssize_t t = 0; t < a->count[j]; t++) {
            const Py_ssize_t q = a->first[j] + t;
            const double cell_lo = q <= 0 ? -INFINITY : (double)q;
            const double cell_hi = q >= n_src - 1 ? INFINITY : (double)q + 1.0;
            const double overlap = (hi < cell_hi ? hi : cell_hi) - (lo > cell_lo ? lo : cell_lo);
            a->weight[j * a->max_taps + t] = (float)((overlap > 0.0 ? overlap : 0.0) / width);
        }
    }
    return 0;
}

/* One region: out (OH, OW, C) float32 or uint8 (rounded to nearest, half up, at most 255) from
 * src (H, W, C) uint8. Rows first: each output row is a weighted sum of source rows over the
 * columns the region reads, then each output pixel a weighted sum of entries of that row. The loops of abi 5,
 * kept as the specification of resample_one's numbers (it must equal them to the bit; `resample_reference`
 * runs them). */
HOT_LOOP_CLONES
static void resample_one_reference(const uint8_t *src, Py_ssize_t W, Py_ssize_t C, const AxisTaps *ty,
                                   const AxisTaps *tx, float *row, void *out, int out_u8)
{
    const Py_ssize_t xmin = tx->first[0];
    const Py_ssize_t xmax = tx->first[tx->n_out - 1] + tx->count[tx->n_out - 1] - 1;
    const Py_ssize_t span = (xmax - xmin + 1) * C;
    const Py_ssize_t OW = tx->n_out;
    memset(row + span, 0, sizeof(float) * (size_t)(tx->max_taps * C));
    for (Py_ssize_t i = 0; i < ty->n_out; i++) {
        memset(row, 0, sizeof(float) * (size_t)span);
        for (Py_ssize_t k = 0; k < ty->count[i]; k++) {
            const float w = ty->weight[i * ty->max_taps + k];
            if (w == 0.0f)
                continue;
            const uint8_t *line = src + ((ty->first[i] + k) * W + xmin) * C;
            for (Py_ssize_t t = 0; t < span; t++)
                row[t] += w * (float)line[t];
        }
        /* Every output uses T taps (unused ones have zero weight and read zeros past the span),
         * so the inner loops have one trip count and the channel loop is unrolled for C = 1, 3. */
        const Py_ssize_t T = tx->max_taps;
        float *acc = row + span + T * C; /* OW * C accumulators after the zero tail */
        if (C == 1 && T == 2) { /* enlarging: bilinear */
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + 2 * j, *rj = row + (tx->first[j] - xmin);
                acc[j] = wj[0] * rj[0] + wj[1] * rj[1];
            }
        } else if (C == 1 && T == 3) {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + 3 * j, *rj = row + (tx->first[j] - xmin);
                acc[j] = wj[0] * rj[0] + wj[1] * rj[1] + wj[2] * rj[2];
            }
        } else if (C == 1) {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + j * T, *rj = row + (tx->first[j] - xmin);
                float a = 0.0f;
                for (Py_ssize_t k = 0; k < T; k++)
                    a += wj[k] * rj[k];
                acc[j] = a;
            }
        } else if (C == 3 && T == 2) {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + 2 * j, *rj = row + (tx->first[j] - xmin) * 3;
                acc[3 * j] = wj[0] * rj[0] + wj[1] * rj[3];
                acc[3 * j + 1] = wj[0] * rj[1] + wj[1] * rj[4];
                acc[3 * j + 2] = wj[0] * rj[2] + wj[1] * rj[5];
            }
        } else if (C == 3) {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + j * T, *rj = row + (tx->first[j] - xmin) * 3;
                float a0 = 0.0f, a1 = 0.0f, a2 = 0.0f;
                for (Py_ssize_t k = 0; k < T; k++) {
                    a0 += wj[k] * rj[3 * k];
                    a1 += wj[k] * rj[3 * k + 1];
                    a2 += wj[k] * rj[3 * k + 2];
                }
                acc[3 * j] = a0;
                acc[3 * j + 1] = a1;
                acc[3 * j + 2] = a2;
            }
        } else {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + j * T, *rj = row + (tx->first[j] - xmin) * C;
                for (Py_ssize_t c = 0; c < C; c++) {
                    float a = 0.0f;
                    for (Py_ssize_t k = 0; k < T; k++)
                        a += wj[k] * rj[k * C + c];
                    acc[j * C + c] = a;
                }
            }
        }
        const Py_ssize_t base = i * OW * C;
        if (out_u8) {
            uint8_t *o = (uint8_t *)out + base;
            /* acc >= 0 (non-negative weights and pixels): adding 0.5 and truncating rounds half up. */
            for (Py_ssize_t t = 0; t < OW * C; t++) {
                const float r = acc[t] + 0.5f;
                o[t] = (uint8_t)(r >= 255.0f ? 255.0f : r);
            }
        } else {
            memcpy((float *)out + base, acc, sizeof(float) * (size_t)(OW * C));
        }
    }
}

/* values >= 0 (non-negative weights and pixels) rounded half up (adding 0.5 and truncating), at most 255, as
 * resample_one_reference does; through int (the same truncation of a value in [0.5, 255]) so that it vectorises. */
static ALWAYS_INLINE void round_to_u8(const float *restrict values, uint8_t *restrict out, Py_ssize_t n)
{
    for (Py_ssize_t t = 0; t < n; t++) {
        const float r = values[t] + 0.5f;
        out[t] = (uint8_t)(int)(r >= 255.0f ? 255.0f : r);
    }
}

/* Images of at most this many values are resampled from a float copy (256 KiB, cache-sized). */
#define RESAMPLE_SOURCE_FLOATS 65536

static ALWAYS_INLINE void widen_u8(const uint8_t *restrict line, float *restrict out, Py_ssize_t n)
{
    for (Py_ssize_t t = 0; t < n; t++)
        out[t] = (float)line[t];
}

/* row = w line (first: the row's first term) or row += w line, as resample_one_reference adds to a zeroed row:
 * 0 + w p (or fma(w, p, 0)) is w p for w, p >= 0. */
static ALWAYS_INLINE void weigh_row(const float *restrict line, float w, float *restrict row, Py_ssize_t n, int add)
{
    if (add) {
        UNROLL4
        for (Py_ssize_t t = 0; t < n; t++)
            row[t] += w * line[t];
    } else {
        UNROLL4
        for (Py_ssize_t t = 0; t < n; t++)
            row[t] = w * line[t];
    }
}

static ALWAYS_INLINE void weigh_row_u8(const uint8_t *restrict line, float w, float *restrict row, Py_ssize_t n,
                                       int add)
{
    if (add) {
        UNROLL4
        for (Py_ssize_t t = 0; t < n; t++)
            row[t] += w * (float)line[t];
    } else {
        UNROLL4
        for (Py_ssize_t t = 0; t < n; t++)
            row[t] = w * (float)line[t];
    }
}

/* One output row of three channels: each output pixel the T weighted entries of the row from its first tap, summed
 * from 0 in tap order (a constant T unrolls the taps' loop; the same terms in the same order). */
static ALWAYS_INLINE void row_taps_c3(const AxisTaps *tx, const float *row, Py_ssize_t xmin, float *acc, Py_ssize_t T)
{
    for (Py_ssize_t j = 0; j < tx->n_out; j++) {
        const float *wj = tx->weight + j * T, *rj = row + (tx->first[j] - xmin) * 3;
        float a0 = 0.0f, a1 = 0.0f, a2 = 0.0f;
        for (Py_ssize_t k = 0; k < T; k++) {
            a0 += wj[k] * rj[3 * k];
            a1 += wj[k] * rj[3 * k + 1];
            a2 += wj[k] * rj[3 * k + 2];
        }
        acc[3 * j] = a0;
        acc[3 * j + 1] = a1;
        acc[3 * j + 2] = a2;
    }
}

/* One region: out (OH, OW, C) float32 or uint8 (rounded to nearest, half up, at most 255) from
 * src (H, W, C) uint8. Rows first: each output row is a weighted sum of source rows over the
 * columns the region reads, then each output pixel a weighted sum of entries of that row. The numbers of
 * resample_one_reference to the bit (the first weighted source row is written rather than added to a zeroed
 * row: weigh_row). */
HOT_LOOP_CLONES
static void resample_one(const uint8_t *src, Py_ssize_t W, Py_ssize_t C, const AxisTaps *ty, const AxisTaps *tx,
                         const float *source, float *row, float *region, void *out, int out_u8)
{
    const Py_ssize_t xmin = tx->first[0];
    const Py_ssize_t xmax = tx->first[tx->n_out - 1] + tx->count[tx->n_out - 1] - 1;
    const Py_ssize_t span = (xmax - xmin + 1) * C;
    const Py_ssize_t OW = tx->n_out;
    memset(row + span, 0, sizeof(float) * (size_t)(tx->max_taps * C));
    for (Py_ssize_t i = 0; i < ty->n_out; i++) {
        int written = 0;
        for (Py_ssize_t k = 0; k < ty->count[i]; k++) {
            const float w = ty->weight[i * ty->max_taps + k];
            if (w == 0.0f)
                continue;
            if (source) /* the image as float (exact): the sums run on floats only, short uint8 rows do not vectorise */
                weigh_row(source + ((ty->first[i] + k) * W + xmin) * C, w, row, span, written);
            else
                weigh_row_u8(src + ((ty->first[i] + k) * W + xmin) * C, w, row, span, written);
            written = 1;
        }
        if (!written)
            memset(row, 0, sizeof(float) * (size_t)span);
        /* Every output uses T taps (unused ones have zero weight and read zeros past the span),
         * so the inner loops have one trip count and the channel loop is unrolled for C = 1, 3. */
        const Py_ssize_t T = tx->max_taps;
        /* The output row (float output) or its row of the region's sums (uint8: converted at the end, in one
         * loop long enough to vectorise). */
        float *acc = (out_u8 ? region : (float *)out) + i * OW * C;
        if (C == 1 && T == 2) { /* enlarging: bilinear */
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + 2 * j, *rj = row + (tx->first[j] - xmin);
                acc[j] = wj[0] * rj[0] + wj[1] * rj[1];
            }
        } else if (C == 1 && T == 3) {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + 3 * j, *rj = row + (tx->first[j] - xmin);
                acc[j] = wj[0] * rj[0] + wj[1] * rj[1] + wj[2] * rj[2];
            }
        } else if (C == 1) {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + j * T, *rj = row + (tx->first[j] - xmin);
                float a = 0.0f;
                for (Py_ssize_t k = 0; k < T; k++)
                    a += wj[k] * rj[k];
                acc[j] = a;
            }
        } else if (C == 3 && T == 2) {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + 2 * j, *rj = row + (tx->first[j] - xmin) * 3;
                acc[3 * j] = wj[0] * rj[0] + wj[1] * rj[3];
                acc[3 * j + 1] = wj[0] * rj[1] + wj[1] * rj[4];
                acc[3 * j + 2] = wj[0] * rj[2] + wj[1] * rj[5];
            }
        } else if (C == 3 && T == 3) { /* shrinking 1-2x: the taps' loop unrolled (the same terms in order) */
            row_taps_c3(tx, row, xmin, acc, 3);
        } else if (C == 3) {
            row_taps_c3(tx, row, xmin, acc, T);
        } else {
            for (Py_ssize_t j = 0; j < OW; j++) {
                const float *wj = tx->weight + j * T, *rj = row + (tx->first[j] - xmin) * C;
                for (Py_ssize_t c = 0; c < C; c++) {
                    float a = 0.0f;
                    for (Py_ssize_t k = 0; k < T; k++)
                        a += wj[k] * rj[k * C + c];
                    acc[j * C + c] = a;
                }
            }
        }
    }
    if (out_u8)
        round_to_u8(region, (uint8_t *)out, ty->n_out * OW * C);
}

/* resample(src, H, W, C, cx, cy, sizes, N, OW, OH, out, out_u8): N regions of sizes (N, 2) float64
 * (w, h) pixels centred at (cx, cy) -> out (N, OH, OW, C). Taps stay in [first, first + count),
 * always inside the image, so no index can leave the source buffer. resample_reference: the same through
 * axis_taps and resample_one_reference (for the tests). */
static PyObject *resample_run(PyObject *args, int reference)
{
    PyObject *o_src, *o_sizes, *o_out;
    Py_ssize_t H, W, C, N, OW, OH;
    double cx, cy;
    int out_u8;
    if (!PyArg_ParseTuple(args, "OnnnddOnnnOp", &o_src, &H, &W, &C, &cx, &cy, &o_sizes, &N, &OW, &OH, &o_out, &out_u8))
        return NULL;
    if (H < 1 || W < 1 || C < 1 || N < 1 || OH < 1 || OW < 1) {
        PyErr_SetString(PyExc_ValueError, "resample: sizes must be positive");
        return NULL;
    }
    Py_buffer src, sizes, out;
    if (get_buffer(o_src, &src, 0, H * W * C, "src") < 0)
        return NULL;
    if (get_buffer(o_sizes, &sizes, 0, N * 2 * (Py_ssize_t)sizeof(double), "sizes") < 0) {
        PyBuffer_Release(&src);
        return NULL;
    }
    if (get_buffer(o_out, &out, 1, N * OH * OW * C * (out_u8 ? 1 : 4), "out") < 0) {
        PyBuffer_Release(&sizes);
        PyBuffer_Release(&src);
        return NULL;
    }
    const double *sz = (const double *)sizes.buf;
    /* Row buffer: the span (<= W pixels), a zero tail of up to W taps, then OW accumulators. */
    float *row = (float *)malloc(sizeof(float) * (size_t)((2 * W + OW) * C));
    int failed = row == NULL;
    if (!reference && !failed) {
        /* The taps of every region in buffers allocated once. */
        AxisTaps tx = {0}, ty = {0};
        Py_ssize_t x_capacity = 0, y_capacity = 0;
        tx.first = (Py_ssize_t *)malloc(sizeof(Py_ssize_t) * (size_t)(2 * OW));
        ty.first = (Py_ssize_t *)malloc(sizeof(Py_ssize_t) * (size_t)(2 * OH));
        float *region = out_u8 ? (float *)malloc(sizeof(float) * (size_t)(OH * OW * C)) : NULL;
        /* A small image (the size filter's grey crop) as float, once for all its regions. */
        float *source = H * W * C <= RESAMPLE_SOURCE_FLOATS ? (float *)malloc(sizeof(float) * (size_t)(H * W * C)) : NULL;
        failed = !tx.first || !ty.first || (out_u8 && !region) || (H * W * C <= RESAMPLE_SOURCE_FLOATS && !source);
        if (!failed && source)
            widen_u8((const uint8_t *)src.buf, source, H * W * C);
        if (!failed) {
            tx.count = tx.first + OW;
            ty.count = ty.first + OH;
        }
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t n = 0; n < N && !failed; n++) {
            if (axis_taps_reusing(cx - 0.5 * sz[2 * n], sz[2 * n], OW, W, &tx, &x_capacity) < 0
                || axis_taps_reusing(cy - 0.5 * sz[2 * n + 1], sz[2 * n + 1], OH, H, &ty, &y_capacity) < 0) {
                failed = 1;
                break;
            }
            void *dst = out_u8 ? (void *)((uint8_t *)out.buf + n * OH * OW * C)
                               : (void *)((float *)out.buf + n * OH * OW * C);
            resample_one((const uint8_t *)src.buf, W, C, &ty, &tx, source, row, region, dst, out_u8);
        }
        Py_END_ALLOW_THREADS
        free(tx.first);
        free(ty.first);
        free(tx.weight);
        free(ty.weight);
        free(region);
        free(source);
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t n = 0; reference && n < N && !failed; n++) {
        AxisTaps ty, tx;
        if (axis_taps(cx - 0.5 * sz[2 * n], sz[2 * n], OW, W, &tx) < 0) {
            failed = 1;
            break;
        }
        if (axis_taps(cy - 0.5 * sz[2 * n + 1], sz[2 * n + 1], OH, H, &ty) < 0) {
            axis_taps_free(&tx);
            failed = 1;
            break;
        }
        void *dst = out_u8 ? (void *)((uint8_t *)out.buf + n * OH * OW * C) : (void *)((float *)out.buf + n * OH * OW * C);
        resample_one_reference((const uint8_t *)src.buf, W, C, &ty, &tx, row, dst, out_u8);
        axis_taps_free(&tx);
        axis_taps_free(&ty);
    }
    Py_END_ALLOW_THREADS
    free(row);
    PyBuffer_Release(&out);
    PyBuffer_Release(&sizes);
    PyBuffer_Release(&src);
    if (failed)
        return PyErr_NoMemory();
    Py_RETURN_NONE;
}

static PyObject *resample(PyObject *self, PyObject *args)
{
    (void)self;
    return resample_run(args, 0);
}

static PyObject *resample_reference(PyObject *self, PyObject *args)
{
    (void)self;
    return resample_run(args, 1);
}

/* ---------------------------------------------------------------------------------------------
 * fHOG, as documented in jsar/features/fhog.py.
 */
#define N_SIGNED 18
#define N_UNSIGNED 9
#define N_FHOG 31
#define TWO_PI 6.28318530717958647692f
#define HALF_PI 1.57079632679489661923f
#define PI_F 3.14159265358979323846f
#define FHOG_CHUNK_PIXELS 2048

/* atan(z) for z in [0, 1]: odd polynomial fitted on Chebyshev nodes, max error 4e-8 rad. */
static inline float atan_unit(float z)
{
    const float t = z * z;
    float p = -4.0733094646e-03f;
    p = p * t + 2.1946611033e-02f;
    p = p * t - 5.6063176730e-02f;
    p = p * t + 9.6562564705e-02f;
    p = p * t - 1.3915802261e-01f;
    p = p * t + 1.9948508986e-01f;
    p = p * t - 3.3330106678e-01f;
    p = p * t + 9.9999943684e-01f;
    return z * p;
}

static void load_row(const void *img, int u8, Py_ssize_t offset, Py_ssize_t n, float *dst)
{
    if (u8) {
        const uint8_t *s = (const uint8_t *)img + offset;
        for (Py_ssize_t i = 0; i < n; i++)
            dst[i] = (float)s[i];
    } else {
        memcpy(dst, (const float *)img + offset, sizeof(float) * (size_t)n);
    }
}

/* Bilinear weights of pixels 0..n-1 on cells 0..cells-1 along one axis: pixel p (centre p + 0.5)
 * gives weight w0[p] to cell c0[p] and 1 - w0[p] to cell c0[p] + 1 (c0 may be -1 or cells - 1;
 * out-of-range cells are skipped by the caller through zero weights: w_lo / w_hi). */
static void axis_cells(Py_ssize_t n, Py_ssize_t cell, Py_ssize_t cells, Py_ssize_t *c0, float *w_lo, float *w_hi)
{
    for (Py_ssize_t p = 0; p < n; p++) {
        const double u = ((double)p + 0.5) / (double)cell - 0.5;
        const double f = floor(u);
        const Py_ssize_t c = (Py_ssize_t)f;
        const float frac = (float)(u - f);
        c0[p] = c;
        w_lo[p] = (c >= 0 && c < cells) ? 1.0f - frac : 0.0f;
        w_hi[p] = (c + 1 >= 0 && c + 1 < cells) ? frac : 0.0f;
    }
}

typedef struct {
    float *gx, *gy, *mag, *pos;      /* one row of pixels */
    float *up, *mid, *dn;            /* source rows y-1, y (padded), y+1, all channels */
    float *row_hist;                 /* (wc + 2) x 18: the row binned along x, cells -1..wc */
    Py_ssize_t *cx0;
    float *wx_lo, *wx_hi;
    Py_ssize_t *cy0;
    float *wy_lo, *wy_hi;
    /* fhog_one only: per-pixel values of a chunk of chunk_rows rows (gradients, orientation, magnitude, its
     * shares of the lower bin and the next, and the two bins' places in row_hist), and each chunk pixel's cell
     * offset (cx0 + 1) * 18 in row_hist */
    float *chunk_gx, *chunk_gy, *chunk_pos, *chunk_mag, *chunk_lo, *chunk_hi;
    int *chunk_k0, *chunk_k1, *chunk_col;
    int *started; /* per cell row: has the histogram row got its first term */
    Py_ssize_t chunk_rows;
} FhogScratch;

/* One image: hist (hc, wc, 18) -> out (hc, wc, 31). The per-pixel work is split into loops the
 * compiler vectorises (gradient, magnitude, angle) and one scalar scatter into a row histogram,
 * which is then spread over the two cell rows it belongs to. The loops of abi 5, kept as the
 * specification of fhog_one's numbers (it must equal them to the bit; `fhog_reference` runs them). */
HOT_LOOP_CLONES
static void fhog_one_reference(const void *img, int u8, Py_ssize_t H, Py_ssize_t W, Py_ssize_t C, Py_ssize_t cell,
                               FhogScratch *sc, float *hist, float *energy, float *out)
{
    const Py_ssize_t hc = H / cell, wc = W / cell;
    const Py_ssize_t hv = hc * cell, wv = wc * cell;
    const float bins_per_rad = (float)N_SIGNED / TWO_PI;
    memset(hist, 0, sizeof(float) * (size_t)(hc * wc * N_SIGNED));

    for (Py_ssize_t y = 0; y < hv; y++) {
        const Py_ssize_t yu = y > 0 ? y - 1 : 0, yd = y + 1 < H ? y + 1 : H - 1;
        float *gxr = sc->gx, *gyr = sc->gy, *mag = sc->mag, *pos = sc->pos;
        /* Rows as float; the middle row padded by one replicated pixel on each side. */
        float *up = sc->up, *dn = sc->dn, *mid = sc->mid;
        load_row(img, u8, y * W * C, W * C, mid + C);
        load_row(img, u8, yu * W * C, W * C, up);
        load_row(img, u8, yd * W * C, W * C, dn);
        for (Py_ssize_t c = 0; c < C; c++) {
            mid[c] = mid[C + c];
            mid[(W + 1) * C + c] = mid[W * C + c];
        }
        if (C == 1) {
            for (Py_ssize_t x = 0; x < wv; x++) {
                gxr[x] = mid[x + 2] - mid[x];
                gyr[x] = dn[x] - up[x];
            }
        } else if (C == 3) {
            /* Channels unrolled (no inner loop) so the x loop vectorises; ties keep the first channel. */
            for (Py_ssize_t x = 0; x < wv; x++) {
                const float gx0 = mid[3 * x + 6] - mid[3 * x], gy0 = dn[3 * x] - up[3 * x];
                const float gx1 = mid[3 * x + 7] - mid[3 * x + 1], gy1 = dn[3 * x + 1] - up[3 * x + 1];
                const float gx2 = mid[3 * x + 8] - mid[3 * x + 2], gy2 = dn[3 * x + 2] - up[3 * x + 2];
                const float m0 = gx0 * gx0 + gy0 * gy0, m1 = gx1 * gx1 + gy1 * gy1, m2 = gx2 * gx2 + gy2 * gy2;
                const int one = m1 > m0;
                float bx = one ? gx1 : gx0, by = one ? gy1 : gy0;
                const float bm = one ? m1 : m0;
                const int two = m2 > bm;
                gxr[x] = two ? gx2 : bx;
                gyr[x] = two ? gy2 : by;
            }
        } else {
            for (Py_ssize_t x = 0; x < wv; x++) {
                float bx = mid[(x + 2) * C] - mid[x * C], by = dn[x * C] - up[x * C];
                float bm = bx * bx + by * by;
                for (Py_ssize_t c = 1; c < C; c++) {
                    const float gx = mid[(x + 2) * C + c] - mid[x * C + c];
                    const float gy = dn[x * C + c] - up[x * C + c];
                    const float m2 = gx * gx + gy * gy;
                    const int better = m2 > bm; /* ties keep the first channel, like numpy's argmax */
                    bx = better ? gx : bx;
                    by = better ? gy : by;
                    bm = better ? m2 : bm;
                }
                gxr[x] = bx;
                gyr[x] = by;
            }
        }
        for (Py_ssize_t x = 0; x < wv; x++) {
            const float gx = gxr[x], gy = gyr[x];
            const float ax = gx < 0.0f ? -gx : gx, ay = gy < 0.0f ? -gy : gy;
            const float lo = ax < ay ? ax : ay, hi = ax < ay ? ay : ax;
            /* Branch-free so the loop vectorises: the zero vector divides 0 by 1. */
            const float z = lo / (hi + (float)(hi == 0.0f));
            float a = atan_unit(z);
            a = ay > ax ? HALF_PI - a : a;
            a = gx < 0.0f ? PI_F - a : a;
            a = gy < 0.0f ? TWO_PI - a : a;
            float p = a * bins_per_rad;
            p = p >= (float)N_SIGNED ? 0.0f : p;
            pos[x] = p;
            mag[x] = sqrtf(gx * gx + gy * gy);
        }
        float *rh = sc->row_hist;
        memset(rh, 0, sizeof(float) * (size_t)((wc + 2) * N_SIGNED));
        for (Py_ssize_t x = 0; x < wv; x++) {
            const float m = mag[x];
            if (m == 0.0f)
                continue;
            const int b0 = (int)pos[x];
            const float fo = pos[x] - (float)b0;
            const int b1 = b0 + 1 == N_SIGNED ? 0 : b0 + 1;
            const float m1 = m * fo, m0 = m - m1;
            float *h0 = rh + (sc->cx0[x] + 1) * N_SIGNED, *h1 = h0 + N_SIGNED;
            const float wl = sc->wx_lo[x], wh = sc->wx_hi[x];
            h0[b0] += wl * m0;
            h0[b1] += wl * m1;
            h1[b0] += wh * m0;
            h1[b1] += wh * m1;
        }
        const Py_ssize_t cy = sc->cy0[y];
        const float wl = sc->wy_lo[y], wh = sc->wy_hi[y];
        const float *src_row = rh + N_SIGNED; /* cell 0 */
        if (wl != 0.0f) {
            float *dst = hist + cy * wc * N_SIGNED;
            for (Py_ssize_t t = 0; t < wc * N_SIGNED; t++)
                dst[t] += wl * src_row[t];
        }
        if (wh != 0.0f) {
            float *dst = hist + (cy + 1) * wc * N_SIGNED;
            for (Py_ssize_t t = 0; t < wc * N_SIGNED; t++)
                dst[t] += wh * src_row[t];
        }
    }

    for (Py_ssize_t t = 0; t < hc * wc; t++) {
        const float *h = hist + t * N_SIGNED;
        float e = 0.0f;
        for (int o = 0; o < N_UNSIGNED; o++) {
            const float u = h[o] + h[o + N_UNSIGNED];
            e += u * u;
        }
        energy[t] = e;
    }
#define ENERGY(i, j) energy[((i) < 0 ? 0 : ((i) >= hc ? hc - 1 : (i))) * wc + ((j) < 0 ? 0 : ((j) >= wc ? wc - 1 : (j)))]
    for (Py_ssize_t i = 0; i < hc; i++) {
        for (Py_ssize_t j = 0; j < wc; j++) {
            float norm[4];
            int k = 0;
            for (int dy = 0; dy < 2; dy++)
                for (int dx = 0; dx < 2; dx++) {
                    const Py_ssize_t a = i + dy - 1, b = j + dx - 1; /* block covers cells a..a+1, b..b+1 */
                    const float block = ENERGY(a, b) + ENERGY(a + 1, b) + ENERGY(a, b + 1) + ENERGY(a + 1, b + 1);
                    norm[k++] = 1.0f / sqrtf(block + 1e-4f);
                }
            const float *h = hist + (i * wc + j) * N_SIGNED;
            float *f = out + (i * wc + j) * N_FHOG;
            float texture[4] = {0.0f, 0.0f, 0.0f, 0.0f};
            for (int o = 0; o < N_SIGNED; o++) {
                float sum = 0.0f;
                for (k = 0; k < 4; k++) {
                    const float hv = h[o] * norm[k];
                    const float v = hv < 0.2f ? hv : 0.2f;
                    sum += v;
                    texture[k] += v;
                }
                f[o] = 0.5f * sum;
            }
            for (int o = 0; o < N_UNSIGNED; o++) {
                const float u = h[o] + h[o + N_UNSIGNED];
                float sum = 0.0f;
                for (k = 0; k < 4; k++)
                {
                    const float uv = u * norm[k];
                    sum += uv < 0.2f ? uv : 0.2f;
                }
                f[N_SIGNED + o] = 0.5f * sum;
            }
            for (k = 0; k < 4; k++)
                f[N_SIGNED + N_UNSIGNED + k] = 0.2357f * texture[k];
        }
    }
#undef ENERGY
}

/* ---- fhog_one: the same numbers as fhog_one_reference with fewer instructions ----
 * Gradient of pixel p of a uint8 image from the byte offsets (in pixels) of its neighbours: right r, left l,
 * down d, up u. Every value is a difference of two integers 0..255, exact in float (and so are the squared
 * magnitudes that pick the channel), so this equals the reference's float rows bit for bit whatever the
 * compiler contracts. Colour: the channel with the largest magnitude, ties keep the first. */
static ALWAYS_INLINE void gradient_u8(const uint8_t *img, Py_ssize_t C, Py_ssize_t r, Py_ssize_t l, Py_ssize_t d,
                                      Py_ssize_t u, float *gx, float *gy)
{
    if (C == 1) {
        *gx = (float)((int)img[r] - (int)img[l]);
        *gy = (float)((int)img[d] - (int)img[u]);
        return;
    }
    float bx = (float)((int)img[r * C] - (int)img[l * C]), by = (float)((int)img[d * C] - (int)img[u * C]);
    float bm = bx * bx + by * by;
    for (Py_ssize_t c = 1; c < C; c++) {
        const float gxc = (float)((int)img[r * C + c] - (int)img[l * C + c]);
        const float gyc = (float)((int)img[d * C + c] - (int)img[u * C + c]);
        const float m2 = gxc * gxc + gyc * gyc;
        const int better = m2 > bm;
        bx = better ? gxc : bx;
        by = better ? gyc : by;
        bm = better ? m2 : bm;
    }
    *gx = bx;
    *gy = by;
}

/* gradient_u8 of pixel (y, x) with its neighbours clamped into the image (the border replicated). */
static ALWAYS_INLINE void gradient_clamped_u8(const uint8_t *img, Py_ssize_t H, Py_ssize_t W, Py_ssize_t C,
                                              Py_ssize_t y, Py_ssize_t x, float *gx, float *gy)
{
    const Py_ssize_t r = y * W + (x + 1 < W ? x + 1 : W - 1), l = y * W + (x > 0 ? x - 1 : 0);
    const Py_ssize_t d = (y + 1 < H ? y + 1 : H - 1) * W + x, u = (y > 0 ? y - 1 : 0) * W + x;
    gradient_u8(img, C, r, l, d, u, gx, gy);
}

/* Gradients of rows y0..y1-1 of a uint8 image (H, W, C) into gx, gy ((y1 - y0) * W, row-major): the rows with
 * both vertical neighbours in one loop over their pixels (its columns 0 and W - 1 read across a row end and
 * are redone), the first and last image rows and the two border columns with clamped (replicated)
 * neighbours. The loops run over whole rows of pixels, not one short row at a time. */
static ALWAYS_INLINE void chunk_gradients_u8(const uint8_t *restrict img, Py_ssize_t H, Py_ssize_t W, Py_ssize_t C,
                                             Py_ssize_t y0, Py_ssize_t y1, float *restrict gx, float *restrict gy)
{
    const Py_ssize_t base = y0 * W;
    const Py_ssize_t ya = y0 > 1 ? y0 : 1, yb = y1 < H - 1 ? y1 : H - 1;
    if (C == 1) {
        for (Py_ssize_t p = ya * W; p < yb * W; p++)
            gradient_u8(img, 1, p + 1, p - 1, p + W, p - W, gx + p - base, gy + p - base);
    } else if (C == 3) {
        for (Py_ssize_t p = ya * W; p < yb * W; p++)
            gradient_u8(img, 3, p + 1, p - 1, p + W, p - W, gx + p - base, gy + p - base);
    } else {
        for (Py_ssize_t p = ya * W; p < yb * W; p++)
            gradient_u8(img, C, p + 1, p - 1, p + W, p - W, gx + p - base, gy + p - base);
    }
    for (Py_ssize_t y = y0; y < y1; y++) {
        if (y == 0 || y == H - 1) {
            for (Py_ssize_t x = 0; x < W; x++)
                gradient_clamped_u8(img, H, W, C, y, x, gx + y * W + x - base, gy + y * W + x - base);
        } else {
            gradient_clamped_u8(img, H, W, C, y, 0, gx + y * W - base, gy + y * W - base);
            if (W > 1)
                gradient_clamped_u8(img, H, W, C, y, W - 1, gx + y * W + W - 1 - base, gy + y * W + W - 1 - base);
        }
    }
}

/* Float images: the reference's gradient loops, row by row into the chunk (inlined: compiled for the clone's
 * target like the reference, so that the magnitudes that pick the channel round as there). */
static ALWAYS_INLINE void row_gradients_f32(const float *img, Py_ssize_t H, Py_ssize_t W, Py_ssize_t C, Py_ssize_t wv,
                                            Py_ssize_t y, FhogScratch *sc, float *gxr, float *gyr)
{
    const Py_ssize_t yu = y > 0 ? y - 1 : 0, yd = y + 1 < H ? y + 1 : H - 1;
    float *up = sc->up, *dn = sc->dn, *mid = sc->mid;
    load_row(img, 0, y * W * C, W * C, mid + C);
    load_row(img, 0, yu * W * C, W * C, up);
    load_row(img, 0, yd * W * C, W * C, dn);
    for (Py_ssize_t c = 0; c < C; c++) {
        mid[c] = mid[C + c];
        mid[(W + 1) * C + c] = mid[W * C + c];
    }
    if (C == 1) {
        for (Py_ssize_t x = 0; x < wv; x++) {
            gxr[x] = mid[x + 2] - mid[x];
            gyr[x] = dn[x] - up[x];
        }
    } else if (C == 3) {
        for (Py_ssize_t x = 0; x < wv; x++) {
            const float gx0 = mid[3 * x + 6] - mid[3 * x], gy0 = dn[3 * x] - up[3 * x];
            const float gx1 = mid[3 * x + 7] - mid[3 * x + 1], gy1 = dn[3 * x + 1] - up[3 * x + 1];
            const float gx2 = mid[3 * x + 8] - mid[3 * x + 2], gy2 = dn[3 * x + 2] - up[3 * x + 2];
            const float m0 = gx0 * gx0 + gy0 * gy0, m1 = gx1 * gx1 + gy1 * gy1, m2 = gx2 * gx2 + gy2 * gy2;
            const int one = m1 > m0;
            float bx = one ? gx1 : gx0, by = one ? gy1 : gy0;
            const float bm = one ? m1 : m0;
            const int two = m2 > bm;
            gxr[x] = two ? gx2 : bx;
            gyr[x] = two ? gy2 : by;
        }
    } else {
        for (Py_ssize_t x = 0; x < wv; x++) {
            float bx = mid[(x + 2) * C] - mid[x * C], by = dn[x * C] - up[x * C];
            float bm = bx * bx + by * by;
            for (Py_ssize_t c = 1; c < C; c++) {
                const float gx = mid[(x + 2) * C + c] - mid[x * C + c];
                const float gy = dn[x * C + c] - up[x * C + c];
                const float m2 = gx * gx + gy * gy;
                const int better = m2 > bm;
                bx = better ? gx : bx;
                by = better ? gy : by;
                bm = better ? m2 : bm;
            }
            gxr[x] = bx;
            gyr[x] = by;
        }
    }
}

/* dst += w src, or dst = w src for a cell row's first term (add = 0): the reference adds it to a zeroed
 * histogram, and 0 + w s (or fma(w, s, 0)) is w s for w > 0, s >= 0. */
static ALWAYS_INLINE void spread_row(const float *restrict src, float w, float *restrict dst, Py_ssize_t n, int add)
{
    if (add) {
        UNROLL4
        for (Py_ssize_t t = 0; t < n; t++)
            dst[t] += w * src[t];
    } else {
        UNROLL4
        for (Py_ssize_t t = 0; t < n; t++)
            dst[t] = w * src[t];
    }
}

/* min(v, 0.2): the reference's `v < 0.2f ? v : 0.2f`. On aarch64 as fminnm (one instruction; GCC keeps the compare
 * and select, as they differ for v = -0 and signalling NaNs): the same value here, where v = h n >= +0 (h a sum of
 * non-negative products, n a positive normaliser) and a quiet NaN gives 0.2 either way. */
#if defined(__aarch64__)
#define CLIP02(v) fminf((v), 0.2f)
#else
#define CLIP02(v) ((v) < 0.2f ? (v) : 0.2f)
#endif
/* The orientation's |gx|, |gy| and their min and max: the reference's compare-and-selects, on aarch64 as fabs,
 * fminnm and fmaxnm (GCC keeps the selects, as they differ for -0 and NaN, and spends about 28 instructions per four
 * pixels on that). The same values for every gradient here: a difference of two equal finite values is +0, never
 * -0, and a finite image has no NaN gradient. */
#if defined(__aarch64__)
#define ABS_F(v) fabsf(v)
#define MIN_F(a, b) fminf((a), (b))
#define MAX_F(a, b) fmaxf((a), (b))
#else
#define ABS_F(v) ((v) < 0.0f ? -(v) : (v))
#define MIN_F(a, b) ((a) < (b) ? (a) : (b))
#define MAX_F(a, b) ((a) < (b) ? (b) : (a))
#endif

/* Each pixel's orientation as a fractional signed bin in [0, 18) and its gradient magnitude, from its gradients
 * (fhog_one_reference's per-pixel numbers). A function of its own, not inlined: inside fhog_one GCC left this loop
 * scalar, with branches, on aarch64. */
static HOT_LOOP_CLONES __attribute__((noinline)) void orientations(const float *restrict gxs, const float *restrict gys,
                                                                     float *restrict pos, float *restrict mag,
                                                                     Py_ssize_t n)
{
    const float bins_per_rad = (float)N_SIGNED / TWO_PI;
    for (Py_ssize_t i = 0; i < n; i++) {
        const float gx = gxs[i], gy = gys[i];
        const float ax = ABS_F(gx), ay = ABS_F(gy);
        const float lo = MIN_F(ax, ay), hi = MAX_F(ax, ay);
        const float z = lo / (hi + (float)(hi == 0.0f));
        float a = atan_unit(z);
        a = ay > ax ? HALF_PI - a : a;
        a = gx < 0.0f ? PI_F - a : a;
        a = gy < 0.0f ? TWO_PI - a : a;
        float p = a * bins_per_rad;
        p = p >= (float)N_SIGNED ? 0.0f : p;
        pos[i] = p;
        mag[i] = sqrtf(gx * gx + gy * gy);
    }
}

/* fhog_one_reference's numbers to the bit (tests/test_features_fhog.py compares the two on real frames and
 * random images) with fewer instructions: the image is processed in chunks of rows, and the per-pixel loops
 * (gradients, orientation and magnitude, now also the bin and the two bins' shares) run over a whole chunk,
 * not one short row at a time; the scatter into the row histogram, the spread over cell rows and every
 * sum add the same terms in the same order as the reference. Each 2x2 block's factor 1 / sqrt(energy + eps)
 * is computed once (`norms`, (hc + 1) x (wc + 1) blocks), not once per cell that uses it, and the per-cell
 * clipping runs over the orientations so that it vectorises. */
HOT_LOOP_CLONES
static void fhog_one(const void *img, int u8, Py_ssize_t H, Py_ssize_t W, Py_ssize_t C, Py_ssize_t cell,
                     FhogScratch *sc, float *hist, float *energy, float *norms, float *out, Py_ssize_t step)
{
    const Py_ssize_t hc = H / cell, wc = W / cell;
    const Py_ssize_t hv = hc * cell, wv = wc * cell;
    float *restrict gxc = sc->chunk_gx, *restrict gyc = sc->chunk_gy;
    float *restrict mlo = sc->chunk_lo, *restrict mhi = sc->chunk_hi;
    float *restrict pos = sc->chunk_pos, *restrict mag = sc->chunk_mag;
    int *restrict k0 = sc->chunk_k0, *restrict k1 = sc->chunk_k1;
    const int *restrict col = sc->chunk_col;
    /* No zeroed histogram: a cell row's first term is written (spread_row), rows never reached zeroed at the end. */
    int *started = sc->started;
    for (Py_ssize_t r = 0; r < hc; r++)
        started[r] = 0;

    for (Py_ssize_t y0 = 0; y0 < hv; y0 += sc->chunk_rows) {
        const Py_ssize_t y1 = y0 + sc->chunk_rows < hv ? y0 + sc->chunk_rows : hv;
        const Py_ssize_t n = (y1 - y0) * W;
        if (u8) {
            chunk_gradients_u8((const uint8_t *)img, H, W, C, y0, y1, gxc, gyc);
        } else {
            for (Py_ssize_t y = y0; y < y1; y++)
                row_gradients_f32((const float *)img, H, W, C, wv, y, sc, gxc + (y - y0) * W, gyc + (y - y0) * W);
            for (Py_ssize_t y = y0; y < y1; y++) /* columns past the last whole cell: defined, never used */
                for (Py_ssize_t x = wv; x < W; x++)
                    gxc[(y - y0) * W + x] = gyc[(y - y0) * W + x] = 0.0f;
        }
        orientations(gxc, gyc, pos, mag, n);
        for (Py_ssize_t i = 0; i < n; i++) { /* the lower bin b0 and the magnitude's shares of b0 and b0 + 1 */
            const float m = mag[i];
            const int b0 = (int)pos[i];
            const float fo = pos[i] - (float)b0;
            const float m1 = m * fo;
            k0[i] = b0;
            mhi[i] = m1;
            mlo[i] = m - m1;
        }
        for (Py_ssize_t i = 0; i < n; i++) { /* the two bins' places in row_hist (bin 17's next is bin 0) */
            const int b0 = k0[i];
            k0[i] = col[i] + b0;
            k1[i] = col[i] + b0 + 1 - (b0 == N_SIGNED - 1) * N_SIGNED;
        }
        for (Py_ssize_t y = y0; y < y1; y++) {
            const Py_ssize_t row = (y - y0) * W;
            float *rh = sc->row_hist;
            memset(rh, 0, sizeof(float) * (size_t)((wc + 2) * N_SIGNED));
            /* A zero-magnitude pixel adds +0 to non-negative sums (the reference skips it): same bits. */
            /* The next cell's bins through a second base pointer: each place is then the base and the 32-bit
             * index the load scales (no 64-bit offsets computed per pixel on aarch64). */
            float *rn = rh + N_SIGNED;
#if defined(__GNUC__)
            __asm__("" : "+r"(rn)); /* opaque: the compiler would fold it back into rh plus 72 bytes a pixel */
#endif
            const int *restrict r0 = k0 + row, *restrict r1 = k1 + row;
            const float *restrict lo_m = mlo + row, *restrict hi_m = mhi + row;
            for (Py_ssize_t x = 0; x < wv; x++) { /* cell cx0 (rh) and the next (rn), bins b0 and b1 */
                const int i0 = r0[x], i1 = r1[x];
                const float m0 = lo_m[x], m1 = hi_m[x];
                const float wl = sc->wx_lo[x], wh = sc->wx_hi[x];
                rh[i0] += wl * m0;
                rh[i1] += wl * m1;
                rn[i0] += wh * m0;
                rn[i1] += wh * m1;
            }
            const Py_ssize_t cy = sc->cy0[y];
            const float wl = sc->wy_lo[y], wh = sc->wy_hi[y];
            const float *src_row = rh + N_SIGNED; /* cell 0 */
            if (wl != 0.0f) {
                spread_row(src_row, wl, hist + cy * wc * N_SIGNED, wc * N_SIGNED, started[cy]);
                started[cy] = 1;
            }
            if (wh != 0.0f) {
                spread_row(src_row, wh, hist + (cy + 1) * wc * N_SIGNED, wc * N_SIGNED, started[cy + 1]);
                started[cy + 1] = 1;
            }
        }
    }
    for (Py_ssize_t r = 0; r < hc; r++)
        if (!started[r])
            memset(hist + r * wc * N_SIGNED, 0, sizeof(float) * (size_t)(wc * N_SIGNED));

    for (Py_ssize_t t = 0; t < hc * wc; t++) {
        const float *h = hist + t * N_SIGNED;
        float e = 0.0f;
        for (int o = 0; o < N_UNSIGNED; o++) {
            const float u = h[o] + h[o + N_UNSIGNED];
            e += u * u;
        }
        energy[t] = e;
    }
    /* Block (a, b) covers cells a..a+1, b..b+1 (clamped to the grid), a in -1..hc-1, b in -1..wc-1. */
#define ENERGY(i, j) energy[((i) < 0 ? 0 : ((i) >= hc ? hc - 1 : (i))) * wc + ((j) < 0 ? 0 : ((j) >= wc ? wc - 1 : (j)))]
    for (Py_ssize_t a = -1; a < hc; a++)
        for (Py_ssize_t b = -1; b < wc; b++) {
            const float block = ENERGY(a, b) + ENERGY(a + 1, b) + ENERGY(a, b + 1) + ENERGY(a + 1, b + 1);
            norms[(a + 1) * (wc + 1) + (b + 1)] = 1.0f / sqrtf(block + 1e-4f);
        }
#undef ENERGY
    for (Py_ssize_t i = 0; i < hc; i++) {
        for (Py_ssize_t j = 0; j < wc; j++) {
            /* The four blocks around cell (i, j), in the reference's order (dy, dx) = 00, 01, 10, 11. */
            const float *above = norms + i * (wc + 1) + j, *below = above + (wc + 1);
            const float n0 = above[0], n1 = above[1], n2 = below[0], n3 = below[1];
            const float *restrict h = hist + (i * wc + j) * N_SIGNED;
            float *restrict f = out + (i * wc + j) * step;
            for (int o = 0; o < N_SIGNED; o++) {
                const float v0 = CLIP02(h[o] * n0), v1 = CLIP02(h[o] * n1);
                const float v2 = CLIP02(h[o] * n2), v3 = CLIP02(h[o] * n3);
                f[o] = 0.5f * ((((0.0f + v0) + v1) + v2) + v3);
            }
            for (int o = 0; o < N_UNSIGNED; o++) {
                const float u = h[o] + h[o + N_UNSIGNED];
                const float v0 = CLIP02(u * n0), v1 = CLIP02(u * n1);
                const float v2 = CLIP02(u * n2), v3 = CLIP02(u * n3);
                f[N_SIGNED + o] = 0.5f * ((((0.0f + v0) + v1) + v2) + v3);
            }
            /* Texture: per block, the clipped signed orientations summed in orientation order. */
#if defined(__GNUC__)
            /* The four blocks as the lanes of one vector (each lane's operations are the scalar ones). */
            typedef float lanes4 __attribute__((vector_size(16)));
            typedef int32_t masks4 __attribute__((vector_size(16)));
            const lanes4 factors = {n0, n1, n2, n3}, clip = {0.2f, 0.2f, 0.2f, 0.2f};
            lanes4 texture = {0.0f, 0.0f, 0.0f, 0.0f};
#if !defined(__clang__)
#pragma GCC unroll 18
#endif
            for (int o = 0; o < N_SIGNED; o++) {
                const lanes4 v = h[o] * factors;
#if defined(__aarch64__)
                texture += (lanes4)vminnmq_f32((float32x4_t)v, (float32x4_t)clip); /* CLIP02 per lane */
#else
                const masks4 below = v < clip;
                texture += (lanes4)(((masks4)v & below) | ((masks4)clip & ~below));
#endif
            }
            const float t0 = texture[0], t1 = texture[1], t2 = texture[2], t3 = texture[3];
#else
            float t0 = 0.0f, t1 = 0.0f, t2 = 0.0f, t3 = 0.0f;
            for (int o = 0; o < N_SIGNED; o++) {
                t0 += h[o] * n0 < 0.2f ? h[o] * n0 : 0.2f;
                t1 += h[o] * n1 < 0.2f ? h[o] * n1 : 0.2f;
                t2 += h[o] * n2 < 0.2f ? h[o] * n2 : 0.2f;
                t3 += h[o] * n3 < 0.2f ? h[o] * n3 : 0.2f;
            }
#endif
            f[N_SIGNED + N_UNSIGNED] = 0.2357f * t0;
            f[N_SIGNED + N_UNSIGNED + 1] = 0.2357f * t1;
            f[N_SIGNED + N_UNSIGNED + 2] = 0.2357f * t2;
            f[N_SIGNED + N_UNSIGNED + 3] = 0.2357f * t3;
        }
    }
}

/* fhog(src, n, h, w, c, is_uint8, cell, out[, step]): src (N, H, W, C) uint8 or float32 -> out float32
 * (N, H//cell, W//cell, 31), or each cell's 31 values `step` floats after the previous cell's (e.g. into channels
 * 1..31 of a 42-channel stack); fhog_reference: the same through fhog_one_reference (step 31, for the tests). */
static PyObject *fhog_run(PyObject *args, int reference)
{
    PyObject *o_src, *o_out;
    Py_ssize_t N, H, W, C, cell, step = N_FHOG;
    int u8;
    if (!PyArg_ParseTuple(args, "OnnnnpnO|n", &o_src, &N, &H, &W, &C, &u8, &cell, &o_out, &step))
        return NULL;
    if (N < 1 || C < 1 || cell < 1 || H < cell || W < cell || step < N_FHOG || (reference && step != N_FHOG)) {
        PyErr_SetString(PyExc_ValueError, "fhog: invalid sizes");
        return NULL;
    }
    const Py_ssize_t hc = H / cell, wc = W / cell;
    Py_buffer src, out;
    if (get_buffer(o_src, &src, 0, N * H * W * C * (u8 ? 1 : 4), "src") < 0)
        return NULL;
    if (get_buffer(o_out, &out, 1, ((N * hc * wc - 1) * step + N_FHOG) * 4, "out") < 0) {
        PyBuffer_Release(&src);
        return NULL;
    }
    /* One block of scratch memory: floats first, then the index arrays. */
    /* fhog_one's chunks: whole rows, about FHOG_CHUNK_PIXELS pixels (cache-sized), at least one row. */
    const Py_ssize_t chunk_rows = W >= FHOG_CHUNK_PIXELS ? 1 : FHOG_CHUNK_PIXELS / W;
    const Py_ssize_t chunk = chunk_rows * W;
    const size_t floats = (size_t)(hc * wc * (N_SIGNED + 1) + (hc + 1) * (wc + 1) + 4 * W + (wc + 2) * N_SIGNED
                                   + 2 * W + 2 * H + (3 * W + 2) * C + 6 * chunk);
    const size_t n_float = floats + (floats & 1); /* even: the index arrays after them stay 8-byte aligned */
    const size_t n_index = (size_t)(W + H);
    const size_t n_int = (size_t)(3 * chunk + hc);
    char *block = (char *)malloc(sizeof(float) * n_float + sizeof(Py_ssize_t) * n_index + sizeof(int) * n_int);
    if (!block) {
        PyBuffer_Release(&out);
        PyBuffer_Release(&src);
        return PyErr_NoMemory();
    }
    float *f = (float *)block;
    float *hist = f;
    f += hc * wc * N_SIGNED;
    float *energy = f;
    f += hc * wc;
    float *norms = f;
    f += (hc + 1) * (wc + 1);
    FhogScratch sc;
    sc.gx = f; f += W;
    sc.gy = f; f += W;
    sc.mag = f; f += W;
    sc.pos = f; f += W;
    sc.row_hist = f; f += (wc + 2) * N_SIGNED;
    sc.wx_lo = f; f += W;
    sc.wx_hi = f; f += W;
    sc.wy_lo = f; f += H;
    sc.wy_hi = f; f += H;
    sc.up = f; f += W * C;
    sc.dn = f; f += W * C;
    sc.mid = f; f += (W + 2) * C;
    sc.chunk_gx = f; f += chunk;
    sc.chunk_gy = f; f += chunk;
    sc.chunk_lo = f; f += chunk;
    sc.chunk_hi = f; f += chunk;
    sc.chunk_pos = f; f += chunk;
    sc.chunk_mag = f; f += chunk;
    Py_ssize_t *idx = (Py_ssize_t *)(block + sizeof(float) * n_float);
    sc.cx0 = idx;
    sc.cy0 = idx + W;
    sc.chunk_k0 = (int *)(idx + n_index);
    sc.chunk_k1 = sc.chunk_k0 + chunk;
    sc.chunk_col = sc.chunk_k1 + chunk;
    sc.started = sc.chunk_col + chunk;
    sc.chunk_rows = chunk_rows;
    axis_cells(W, cell, wc, sc.cx0, sc.wx_lo, sc.wx_hi);
    axis_cells(H, cell, hc, sc.cy0, sc.wy_lo, sc.wy_hi);
    for (Py_ssize_t i = 0; i < chunk; i++)
        sc.chunk_col[i] = (int)((sc.cx0[i % W] + 1) * N_SIGNED);
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t n = 0; n < N; n++) {
        const void *img = u8 ? (const void *)((const uint8_t *)src.buf + n * H * W * C)
                             : (const void *)((const float *)src.buf + n * H * W * C);
        float *dst = (float *)out.buf + n * hc * wc * step;
        if (reference)
            fhog_one_reference(img, u8, H, W, C, cell, &sc, hist, energy, dst);
        else
            fhog_one(img, u8, H, W, C, cell, &sc, hist, energy, norms, dst, step);
    }
    Py_END_ALLOW_THREADS
    free(block);
    PyBuffer_Release(&out);
    PyBuffer_Release(&src);
    Py_RETURN_NONE;
}

static PyObject *fhog(PyObject *self, PyObject *args)
{
    (void)self;
    return fhog_run(args, 0);
}

static PyObject *fhog_reference(PyObject *self, PyObject *args)
{
    (void)self;
    return fhog_run(args, 1);
}

/* The loops of abi 5 (row by row, the cells' sums in `o`), kept as the specification of colour_cells_one's
 * numbers (it must equal them to the bit; `colour_cells_reference` runs them). */
HOT_LOOP_CLONES
static void colour_cells_one_reference(const uint8_t *s, Py_ssize_t W, const float *tab, Py_ssize_t K, Py_ssize_t cell,
                                       Py_ssize_t hc, Py_ssize_t wc, float *o)
{
    memset(o, 0, sizeof(float) * (size_t)(hc * wc * K));
    for (Py_ssize_t y = 0; y < hc * cell; y++) {
        float *cells = o + (y / cell) * wc * K;
        const uint8_t *p = s + y * W * 3;
        for (Py_ssize_t cx = 0; cx < wc; cx++) { /* cell by cell: no division per pixel */
            float *acc = cells + cx * K;
            for (Py_ssize_t dx = 0; dx < cell; dx++, p += 3) {
                const float *entry = tab + (Py_ssize_t)((p[2] >> 3) + 32 * (p[1] >> 3) + 1024 * (p[0] >> 3)) * K;
                if (K == 10) { /* the derived and the original tables: a fixed count the compiler unrolls */
                    for (int k = 0; k < 10; k++)
                        acc[k] += entry[k];
                } else {
                    for (Py_ssize_t k = 0; k < K; k++)
                        acc[k] += entry[k];
                }
            }
        }
    }
    const float inv = 1.0f / (float)(cell * cell);
    for (Py_ssize_t t = 0; t < hc * wc * K; t++)
        o[t] *= inv;
}

/* Cell by cell with the sums in registers: each cell adds its pixels' table rows in the reference's order
 * (rows top to bottom, pixels left to right), from 0, then scales by 1 / cell^2: the same numbers. A pixel's
 * table offset (r//8 + 32 (g//8) + 1024 (b//8)) K is the sum of three looked-up terms, one per channel. */
HOT_LOOP_CLONES
static void colour_cells_one(const uint8_t *s, Py_ssize_t W, const float *tab, Py_ssize_t K, Py_ssize_t cell,
                             Py_ssize_t hc, Py_ssize_t wc, float *o, Py_ssize_t step)
{
    const float inv = 1.0f / (float)(cell * cell);
    /* Each channel's share of a pixel's table row, in bytes (no scaling of the sum per pixel). */
    Py_ssize_t term_b[256], term_g[256], term_r[256];
    for (int v = 0; v < 256; v++) {
        term_b[v] = (Py_ssize_t)(1024 * (v >> 3)) * K * (Py_ssize_t)sizeof(float);
        term_g[v] = (Py_ssize_t)(32 * (v >> 3)) * K * (Py_ssize_t)sizeof(float);
        term_r[v] = (Py_ssize_t)(v >> 3) * K * (Py_ssize_t)sizeof(float);
    }
#define COLOUR_ROW(p) ((const float *)((const char *)tab + term_b[(p)[0]] + term_g[(p)[1]] + term_r[(p)[2]]))
    for (Py_ssize_t cy = 0; cy < hc; cy++)
        for (Py_ssize_t cx = 0; cx < wc; cx++) {
            const uint8_t *corner = s + (cy * cell * W + cx * cell) * 3;
            float *dst = o + (cy * wc + cx) * step;
            if (K == 10) { /* the derived and the original tables: a fixed count the compiler unrolls */
#if defined(__GNUC__)
                /* The ten sums as lanes of vectors of 4, 4 and 2 (each lane adds the same terms in the same order as
                 * a scalar sum; on aarch64 GCC otherwise kept four of the ten sums scalar). */
                typedef float sums4 __attribute__((vector_size(16), aligned(4), may_alias)); /* read from the table's floats */
                typedef float sums2 __attribute__((vector_size(8), aligned(4), may_alias));
                sums4 lo = {0.0f, 0.0f, 0.0f, 0.0f}, mid = {0.0f, 0.0f, 0.0f, 0.0f};
                sums2 hi = {0.0f, 0.0f};
                for (Py_ssize_t dy = 0; dy < cell; dy++) {
                    const uint8_t *p = corner + dy * W * 3;
                    for (Py_ssize_t dx = 0; dx < cell; dx++, p += 3) {
                        const float *entry = COLOUR_ROW(p);
                        lo += *(const sums4 *)entry;
                        mid += *(const sums4 *)(entry + 4);
                        hi += *(const sums2 *)(entry + 8);
                    }
                }
                const float acc[10] = {lo[0], lo[1], lo[2], lo[3], mid[0], mid[1], mid[2], mid[3], hi[0], hi[1]};
#else
                float acc[10] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
                for (Py_ssize_t dy = 0; dy < cell; dy++) {
                    const uint8_t *p = corner + dy * W * 3;
                    for (Py_ssize_t dx = 0; dx < cell; dx++, p += 3) {
                        const float *entry = COLOUR_ROW(p);
                        for (int k = 0; k < 10; k++)
                            acc[k] += entry[k];
                    }
                }
#endif
                for (int k = 0; k < 10; k++)
                    dst[k] = acc[k] * inv;
            } else {
                for (Py_ssize_t k = 0; k < K; k++)
                    dst[k] = 0.0f;
                for (Py_ssize_t dy = 0; dy < cell; dy++) {
                    const uint8_t *p = corner + dy * W * 3;
                    for (Py_ssize_t dx = 0; dx < cell; dx++, p += 3) {
                        const float *entry = COLOUR_ROW(p);
                        for (Py_ssize_t k = 0; k < K; k++)
                            dst[k] += entry[k];
                    }
                }
                for (Py_ssize_t k = 0; k < K; k++)
                    dst[k] *= inv;
            }
        }
#undef COLOUR_ROW
}

/* ---------------------------------------------------------------------------------------------
 * colour_cells(src, h, w, table, channels, cell, out[, step]): mean over each cell of table[row(pixel)],
 * row = r//8 + 32*(g//8) + 1024*(b//8) of the uint8 BGR pixel; out float32 (H//cell, W//cell, channels), or each
 * cell's values `step` floats after the previous cell's (into a channel stack); colour_cells_reference: the same
 * through colour_cells_one_reference (step = channels, for the tests).
 */
static PyObject *colour_cells_run(PyObject *args, int reference)
{
    PyObject *o_src, *o_table, *o_out;
    Py_ssize_t H, W, K, cell, step = -1;
    if (!PyArg_ParseTuple(args, "OnnOnnO|n", &o_src, &H, &W, &o_table, &K, &cell, &o_out, &step))
        return NULL;
    if (step == -1)
        step = K;
    if (K < 1 || cell < 1 || H < cell || W < cell || step < K || (reference && step != K)) {
        PyErr_SetString(PyExc_ValueError, "colour_cells: invalid sizes");
        return NULL;
    }
    const Py_ssize_t hc = H / cell, wc = W / cell;
    Py_buffer src, table, out;
    if (get_buffer(o_src, &src, 0, H * W * 3, "src") < 0)
        return NULL;
    if (get_buffer(o_table, &table, 0, 32768 * K * 4, "table") < 0) {
        PyBuffer_Release(&src);
        return NULL;
    }
    if (get_buffer(o_out, &out, 1, ((hc * wc - 1) * step + K) * 4, "out") < 0) {
        PyBuffer_Release(&table);
        PyBuffer_Release(&src);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    if (reference)
        colour_cells_one_reference((const uint8_t *)src.buf, W, (const float *)table.buf, K, cell, hc, wc,
                                   (float *)out.buf);
    else
        colour_cells_one((const uint8_t *)src.buf, W, (const float *)table.buf, K, cell, hc, wc, (float *)out.buf,
                         step);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&out);
    PyBuffer_Release(&table);
    PyBuffer_Release(&src);
    Py_RETURN_NONE;
}

static PyObject *colour_cells(PyObject *self, PyObject *args)
{
    (void)self;
    return colour_cells_run(args, 0);
}

static PyObject *colour_cells_reference(PyObject *self, PyObject *args)
{
    (void)self;
    return colour_cells_run(args, 1);
}

/* ---------------------------------------------------------------------------------------------
 * One STRCF ADMM iteration's element-wise work (the numpy reference is jsar/dcf.py's admm_solve with
 * kernel=False). Spectra are (C, M) complex64 channel-major, M = H * (W//2+1) frequencies; the label,
 * sxx and the per-frequency solve are per frequency. Iteration 0 computes the terms that stay fixed:
 *     constant = x conj(y) + mu_n f_prev (f_prev optional),  sxx = sum_c |x_c|^2,  rhs = constant.
 * Later iterations first finish the previous iteration (its g-step's element-wise term and dual step):
 *     g += box_weight * numerator (the previous numerator; skipped when box_weight is 0),
 *     h += p_prev (q - g),  rhs = p g + constant - h.
 * Then the f-step by Sherman-Morrison over channels, per frequency:
 *     q = (rhs - x (sum_c conj(x_c) rhs_c) / (sxx + mu_n + p)) / (mu_n + p),
 * and, unless it is the last iteration, the next g-step's numerator p q + h.
 * Frequencies are processed in blocks so that the two passes over the channels of a block (the
 * channel sum, then the solve) run on data still in cache: one trip through memory per iteration.
 *
 * Rounding is the reference's, operation for operation, so that the kernel gives numpy's numbers to the
 * bit where numpy's complex64 multiply uses FMA (x86-64 with AVX2/FMA, checked by tests/test_dcf_kernel.py):
 * a complex product a b is (fma(ar, br, -(ai bi)), fma(ar, bi, ai br)) as numpy computes it, channel sums run
 * in channel order, and nothing else is contracted into an FMA (the pragma below). Float rounding is not
 * noise to a tracker: one sequence of *more* moved from AUC 0.700 to 0.483 on rounding alone. */
#define ADMM_BLOCK 64
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#elif defined(__GNUC__)
#pragma GCC push_options
#pragma GCC optimize("fp-contract=off")
#endif

typedef struct {
    const float *x, *label, *prev;   /* sample (C, M), label (M), previous filter (C, M) or NULL */
    float *constant, *sxx;           /* (C, M) and (M): written at iteration 0, read afterwards */
    float *q, *g, *h, *numerator;    /* (C, M) each; g also gets the box term added */
    Py_ssize_t C, M;
    float mu_n, p_prev, p, box_weight, inv_total, shift;  /* shift: mu_n + p rounded once, as the reference */
    int first, last;
} AdmmStep;

/* Iteration 0's right-hand side of n frequencies of one channel: constant = q = x conj(y) (+ mu_n prev);
 * adds |x|^2 to sxx and conj(x) q to (cr, ci). Branches sit outside the loops so that they vectorise. */
static inline void admm_rhs_first(const float *restrict x, const float *restrict y, const float *restrict prev,
                                  float mu_n, float *restrict con, float *restrict q, float *restrict sxx,
                                  float *restrict cr, float *restrict ci, Py_ssize_t n)
{
    for (Py_ssize_t j = 0; j < n; j++) {
        const float xr = x[2 * j], xi = x[2 * j + 1], yr = y[2 * j], yi = y[2 * j + 1];
        con[2 * j] = fmaf(xr, yr, xi * yi); /* x conj(y), numpy's complex product */
        con[2 * j + 1] = fmaf(xr, -yi, xi * yr);
    }
    if (prev)
        for (Py_ssize_t j = 0; j < 2 * n; j++)
            con[j] = con[j] + mu_n * prev[j];
    for (Py_ssize_t j = 0; j < n; j++) {
        const float xr = x[2 * j], xi = x[2 * j + 1], br = con[2 * j], bi = con[2 * j + 1];
        q[2 * j] = br;
        q[2 * j + 1] = bi;
        sxx[j] = sxx[j] + fmaf(xr, xr, xi * xi); /* conj(x) x */
        cr[j] = cr[j] + fmaf(xr, br, xi * bi);     /* conj(x) q */
        ci[j] = ci[j] + fmaf(xr, bi, -(xi * br));
    }
}

/* A later iteration's right-hand side of n frequencies of one channel: g += box_weight * num (num may be
 * NULL: no box term), h += p_prev (q - g), q = p g + constant - h; adds conj(x) q to (cr, ci). */
static inline void admm_rhs_later(const float *restrict x, const float *restrict con, const float *restrict g,
                                  const float *restrict num, float box_weight, float p_prev, float p,
                                  float *restrict h, float *restrict q, float *restrict cr, float *restrict ci,
                                  Py_ssize_t n)
{
    float gbox[2 * ADMM_BLOCK];
    if (num)
        for (Py_ssize_t j = 0; j < 2 * n; j++)
            gbox[j] = g[j] + box_weight * num[j];
    else
        memcpy(gbox, g, sizeof(float) * (size_t)(2 * n));
    for (Py_ssize_t j = 0; j < 2 * n; j++) {
        const float hj = h[j] + p_prev * (q[j] - gbox[j]);
        h[j] = hj;
        q[j] = (p * gbox[j] + con[j]) - hj;
    }
    for (Py_ssize_t j = 0; j < n; j++) {
        const float xr = x[2 * j], xi = x[2 * j + 1], br = q[2 * j], bi = q[2 * j + 1];
        cr[j] = cr[j] + fmaf(xr, br, xi * bi);
        ci[j] = ci[j] + fmaf(xr, bi, -(xi * br));
    }
}

HOT_LOOP_CLONES
static void strcf_f_step_blocks(const AdmmStep *s)
{
    const Py_ssize_t C = s->C, M = s->M;
    const float mu_n = s->mu_n, p_prev = s->p_prev, p = s->p, box_weight = s->box_weight, inv_total = s->inv_total;
    const float shift = s->shift;
    float cr[ADMM_BLOCK], ci[ADMM_BLOCK], inv[ADMM_BLOCK];
    for (Py_ssize_t k0 = 0; k0 < M; k0 += ADMM_BLOCK) {
        const Py_ssize_t n = M - k0 < ADMM_BLOCK ? M - k0 : ADMM_BLOCK;
        float *sxx = s->sxx + k0;
        for (Py_ssize_t j = 0; j < n; j++)
            cr[j] = ci[j] = 0.0f;
        if (s->first)
            for (Py_ssize_t j = 0; j < n; j++)
                sxx[j] = 0.0f;
        /* Pass 1: right-hand side into q, the channel sum conj(x) rhs into (cr, ci). */
        for (Py_ssize_t c = 0; c < C; c++) {
            const Py_ssize_t o = 2 * (c * M + k0);
            if (s->first)
                admm_rhs_first(s->x + o, s->label + 2 * k0, s->prev ? s->prev + o : NULL, mu_n, s->constant + o,
                               s->q + o, sxx, cr, ci, n);
            else
                admm_rhs_later(s->x + o, s->constant + o, s->g + o, box_weight != 0.0f ? s->numerator + o : NULL,
                               box_weight, p_prev, p, s->h + o, s->q + o, cr, ci, n);
        }
        for (Py_ssize_t j = 0; j < n; j++)
            inv[j] = 1.0f / (sxx[j] + shift);
        for (Py_ssize_t j = 0; j < n; j++) {
            cr[j] *= inv[j];
            ci[j] *= inv[j];
        }
        /* Pass 2: the solve, and the next g-step's numerator. */
        for (Py_ssize_t c = 0; c < C; c++) {
            const Py_ssize_t o = 2 * (c * M + k0);
            const float *x = s->x + o, *h = s->h + o;
            float *q = s->q + o, *num = s->numerator + o;
            if (s->last) {
                for (Py_ssize_t j = 0; j < n; j++) {
                    const float xr = x[2 * j], xi = x[2 * j + 1];
                    q[2 * j] = (q[2 * j] - fmaf(xr, cr[j], -(xi * ci[j]))) * inv_total;
                    q[2 * j + 1] = (q[2 * j + 1] - fmaf(xr, ci[j], xi * cr[j])) * inv_total;
                }
            } else { /* h is zero on the first iteration, as in the reference, which adds it there too */
                for (Py_ssize_t j = 0; j < n; j++) {
                    const float xr = x[2 * j], xi = x[2 * j + 1];
                    const float fr = (q[2 * j] - fmaf(xr, cr[j], -(xi * ci[j]))) * inv_total;
                    const float fi = (q[2 * j + 1] - fmaf(xr, ci[j], xi * cr[j])) * inv_total;
                    q[2 * j] = fr;
                    q[2 * j + 1] = fi;
                    num[2 * j] = p * fr + h[2 * j];
                    num[2 * j + 1] = p * fi + h[2 * j + 1];
                }
            }
        }
    }
}

#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC pop_options
#endif

/* strcf_f_step(x, label, prev, constant, sxx, q, g, h, numerator, C, M, mu_n, p_prev, p, box_weight,
 *              inv_total, first, last): one iteration as documented above strcf_f_step_blocks; prev may be
 * None (no temporal term). inv_total is 1 / (mu_n + p) rounded to float32, as the reference uses it. */
static PyObject *strcf_f_step(PyObject *self, PyObject *args)
{
    (void)self;
    enum { X, LABEL, PREV, CONSTANT, SXX, Q, G, H, NUM, N_BUF };
    static const char *const names[N_BUF] = {"x", "label", "prev", "constant", "sxx", "q", "g", "h", "numerator"};
    PyObject *objs[N_BUF];
    Py_ssize_t C, M;
    double mu_n, p_prev, p, box_weight, inv_total;
    int first, last;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOnndddddpp", &objs[X], &objs[LABEL], &objs[PREV], &objs[CONSTANT], &objs[SXX],
                          &objs[Q], &objs[G], &objs[H], &objs[NUM], &C, &M, &mu_n, &p_prev, &p, &box_weight,
                          &inv_total, &first, &last))
        return NULL;
    if (C < 1 || M < 1) {
        PyErr_SetString(PyExc_ValueError, "strcf_f_step: sizes must be positive");
        return NULL;
    }
    Py_buffer views[N_BUF];
    int held[N_BUF] = {0};
    int failed = 0;
    for (int b = 0; b < N_BUF && !failed; b++) {
        if (b == PREV && objs[b] == Py_None)
            continue;
        const int per_frequency = b == LABEL || b == SXX;
        const int writable = b >= CONSTANT && b != G;
        const int complex_items = b != SXX;
        failed = get_buffer_of(objs[b], &views[b], writable, (per_frequency ? M : C * M) * (complex_items ? 8 : 4),
                               complex_items ? "Zf" : "f", names[b]) < 0;
        held[b] = !failed;
    }
    /* The buffers written must not be one another or an input: the passes read them after writing. */
    for (int a = CONSTANT; a < N_BUF && !failed; a++)
        for (int b = 0; b < N_BUF && !failed; b++)
            if (a != G && a != b && held[a] && held[b] && views[a].buf == views[b].buf) {
                PyErr_Format(PyExc_ValueError, "strcf_f_step: %s and %s are the same buffer", names[a], names[b]);
                failed = 1;
            }
    if (!failed) {
        AdmmStep s = {
            .x = (const float *)views[X].buf, .label = (const float *)views[LABEL].buf,
            .prev = held[PREV] ? (const float *)views[PREV].buf : NULL,
            .constant = (float *)views[CONSTANT].buf, .sxx = (float *)views[SXX].buf, .q = (float *)views[Q].buf,
            .g = (float *)views[G].buf, .h = (float *)views[H].buf, .numerator = (float *)views[NUM].buf,
            .C = C, .M = M, .mu_n = (float)mu_n, .p_prev = (float)p_prev, .p = (float)p,
            .box_weight = (float)box_weight, .inv_total = (float)inv_total, .shift = (float)(mu_n + p),
            .first = first, .last = last,
        };
        Py_BEGIN_ALLOW_THREADS
        strcf_f_step_blocks(&s);
        Py_END_ALLOW_THREADS
    }
    for (int b = 0; b < N_BUF; b++)
        if (held[b])
            PyBuffer_Release(&views[b]);
    if (failed)
        return NULL;
    Py_RETURN_NONE;
}

/* ---------------------------------------------------------------------------------------------
 * The size filter's spectra over its (S, A) grid (the specification is size_filter.grid_spectrum_reference:
 * rfft2 over the grid axes of the windowed sample, half spectrum along A). Channels (D, contiguous) are the
 * vector axis, processed in blocks of GRID_BLOCK held in registers:
 *   step 1, along A (real input): t[s][j] = sum_a w[s][a] x[s][a] exp(-2 pi i j a / A), j = 0..A/2, planar
 *           (re, im) rows of D in `scratch`;
 *   step 2, along S (complex input): rows k and S - k of exp(-2 pi i k s / S) share cos and negate sin, so
 *           P = sum_s cos_s[k][s] t[s][j] and Q = sum_s sin_s[k][s] t[s][j] give out[k] = P - iQ and
 *           out[S - k] = P + iQ for k = 0..S/2: half the products of a full transform.
 * cos_a, sin_a: (A/2+1, A); cos_s, sin_s: (S/2+1, S) (float32, sin of k = 0 and k = S/2 exactly 0). */
#define GRID_MAX_SIDE 64
/* Four floats as one value (GCC / clang vector extension: one NEON or SSE register; a size every target has,
 * so that it never goes through memory), loadable from any float address: accumulators stay in registers. */
typedef float GridVec __attribute__((vector_size(16), aligned(4), may_alias));
#define GRID_BLOCK 4

/* Step 1 of grid_spectrum_run for channels [d0, d0 + 4 n) (n GridVecs, n <= 4): t = sum_a (cr[a], ci[a]) x[a]. */
static ALWAYS_INLINE void grid_step1_block(const float *restrict xs, const float *restrict cr,
                                           const float *restrict ci, float *restrict tr, float *restrict ti,
                                           Py_ssize_t A, Py_ssize_t D, Py_ssize_t d0, int n)
{
    GridVec re[4] = {{0}}, im[4] = {{0}};
    for (Py_ssize_t a = 0; a < A; a++) {
        const float *xa = xs + a * D + d0;
        const float c = cr[a], sn = ci[a];
        for (int q = 0; q < n; q++) {
            const GridVec v = *(const GridVec *)(xa + q * GRID_BLOCK);
            re[q] += c * v;
            im[q] += sn * v;
        }
    }
    for (int q = 0; q < n; q++) {
        *(GridVec *)(tr + d0 + q * GRID_BLOCK) = re[q];
        *(GridVec *)(ti + d0 + q * GRID_BLOCK) = im[q];
    }
}

/* Step 2 of grid_spectrum_run for channels [d0, d0 + 4 n) (n <= 2) of column j, rows k and S - k. */
static ALWAYS_INLINE void grid_step2_block(const float *restrict scratch, const float *restrict cs,
                                           const float *restrict ss, float *restrict lo, float *restrict hi,
                                           int mirrored, Py_ssize_t S, Py_ssize_t stride, Py_ssize_t D,
                                           Py_ssize_t d0, int n)
{
    GridVec pr[2] = {{0}}, pi[2] = {{0}}, qr[2] = {{0}}, qi[2] = {{0}};
    for (Py_ssize_t s = 0; s < S; s++) {
        const float *tr = scratch + s * stride + d0, *ti = tr + D;
        const float c = cs[s], sn = ss[s];
        for (int q = 0; q < n; q++) {
            const GridVec vr = *(const GridVec *)(tr + q * GRID_BLOCK), vi = *(const GridVec *)(ti + q * GRID_BLOCK);
            pr[q] += c * vr;
            pi[q] += c * vi;
            qr[q] += sn * vr;
            qi[q] += sn * vi;
        }
    }
    for (int q = 0; q < n; q++) {
        const GridVec lo_re = pr[q] + qi[q], lo_im = pi[q] - qr[q], hi_re = pr[q] - qi[q], hi_im = pi[q] + qr[q];
        float *l = lo + 2 * (d0 + q * GRID_BLOCK), *h = hi + 2 * (d0 + q * GRID_BLOCK);
        for (int e = 0; e < GRID_BLOCK; e++) {
            l[2 * e] = lo_re[e];
            l[2 * e + 1] = lo_im[e];
        }
        if (mirrored)
            for (int e = 0; e < GRID_BLOCK; e++) {
                h[2 * e] = hi_re[e];
                h[2 * e + 1] = hi_im[e];
            }
    }
}

static HOT_LOOP_CLONES void grid_spectrum_run(const float *restrict x, const float *restrict w,
                                              const float *restrict cos_a, const float *restrict sin_a,
                                              const float *restrict cos_s, const float *restrict sin_s,
                                              float *restrict scratch, float *restrict out, Py_ssize_t S,
                                              Py_ssize_t A, Py_ssize_t D)
{
    const Py_ssize_t A2 = A / 2 + 1, S2 = S / 2 + 1, blocked = D - D % GRID_BLOCK;
    float cr[GRID_MAX_SIDE], ci[GRID_MAX_SIDE];
    for (Py_ssize_t s = 0; s < S; s++) {
        const float *xs = x + s * A * D;
        for (Py_ssize_t j = 0; j < A2; j++) {
            for (Py_ssize_t a = 0; a < A; a++) {
                cr[a] = cos_a[j * A + a] * w[s * A + a];
                ci[a] = -sin_a[j * A + a] * w[s * A + a];
            }
            float *tr = scratch + (s * A2 + j) * 2 * D, *ti = tr + D;
            Py_ssize_t d0 = 0;
            for (; d0 + 4 * GRID_BLOCK <= blocked; d0 += 4 * GRID_BLOCK)
                grid_step1_block(xs, cr, ci, tr, ti, A, D, d0, 4);
            for (; d0 < blocked; d0 += GRID_BLOCK)
                grid_step1_block(xs, cr, ci, tr, ti, A, D, d0, 1);
            for (Py_ssize_t d = blocked; d < D; d++) {
                float re = 0.0f, im = 0.0f;
                for (Py_ssize_t a = 0; a < A; a++) {
                    re += cr[a] * xs[a * D + d];
                    im += ci[a] * xs[a * D + d];
                }
                tr[d] = re;
                ti[d] = im;
            }
        }
    }
    for (Py_ssize_t j = 0; j < A2; j++) {
        for (Py_ssize_t k = 0; k < S2; k++) {
            const int mirrored = k > 0 && 2 * k != S;
            /* row S - k exists only when mirrored (row S would be past the end); else hi is never written */
            float *lo = out + (k * A2 + j) * 2 * D, *hi = mirrored ? out + ((S - k) * A2 + j) * 2 * D : lo;
            const float *cs = cos_s + k * S, *ss = sin_s + k * S, *column = scratch + j * 2 * D;
            const Py_ssize_t stride = A2 * 2 * D;
            Py_ssize_t d0 = 0;
            for (; d0 + 2 * GRID_BLOCK <= blocked; d0 += 2 * GRID_BLOCK)
                grid_step2_block(column, cs, ss, lo, hi, mirrored, S, stride, D, d0, 2);
            for (; d0 < blocked; d0 += GRID_BLOCK)
                grid_step2_block(column, cs, ss, lo, hi, mirrored, S, stride, D, d0, 1);
            for (Py_ssize_t d = blocked; d < D; d++) {
                float pr = 0.0f, pi = 0.0f, qr = 0.0f, qi = 0.0f;
                for (Py_ssize_t s = 0; s < S; s++) {
                    const float vr = column[s * stride + d], vi = column[s * stride + D + d];
                    pr += cs[s] * vr;
                    pi += cs[s] * vi;
                    qr += ss[s] * vr;
                    qi += ss[s] * vi;
                }
                lo[2 * d] = pr + qi;
                lo[2 * d + 1] = pi - qr;
                if (mirrored) {
                    hi[2 * d] = pr - qi;
                    hi[2 * d + 1] = pi + qr;
                }
            }
        }
    }
}

/* Buffers objs[0..n) as views: need[i] bytes at least, item type code[i] ("f", "Zf"), writable when
 * writable[i]; the error names names[i]. Returns how many views are held (n on success; fewer after an error, which
 * is set): release them with release_views. Then, if one of the first `distinct` buffers shares its memory with
 * another of them, a ValueError saying they must be distinct, and -1 - n. */
static int acquire_views(PyObject *const *objs, Py_buffer *views, int n, const Py_ssize_t *need,
                         const char *const *code, const int *writable, const char *const *names, int distinct,
                         const char *function)
{
    int held = 0;
    for (; held < n; held++)
        if (get_buffer_of(objs[held], &views[held], writable[held], need[held], code[held], names[held]) < 0)
            return held;
    for (int i = 0; i < distinct; i++)
        for (int j = i + 1; j < distinct; j++)
            if (views[i].buf == views[j].buf) {
                PyErr_Format(PyExc_ValueError, "%s: %s and %s must be distinct buffers", function, names[i], names[j]);
                return -1 - n;
            }
    return n;
}

static void release_views(Py_buffer *views, int held)
{
    for (int i = 0; i < held; i++)
        PyBuffer_Release(&views[i]);
}

/* grid_spectrum(x, window, cos_a, sin_a, cos_s, sin_s, scratch, out, S, A, D): out (S, A/2+1, D) complex64
 * from x (S, A, D) float32 and window (S, A); scratch: S * (A/2+1) * 2 * D float32. */
static PyObject *grid_spectrum(PyObject *self, PyObject *args)
{
    (void)self;
    enum { X, SCRATCH, OUT, WIN, COS_A, SIN_A, COS_S, SIN_S, N_BUF };
    static const char *const names[N_BUF] = {"x", "scratch", "out", "window", "cos_a", "sin_a", "cos_s", "sin_s"};
    static const char *const codes[N_BUF] = {"f", "f", "Zf", "f", "f", "f", "f", "f"};
    static const int writable[N_BUF] = {0, 1, 1, 0, 0, 0, 0, 0};
    PyObject *objs[N_BUF];
    Py_ssize_t S, A, D;
    if (!PyArg_ParseTuple(args, "OOOOOOOOnnn", &objs[X], &objs[WIN], &objs[COS_A], &objs[SIN_A], &objs[COS_S],
                          &objs[SIN_S], &objs[SCRATCH], &objs[OUT], &S, &A, &D))
        return NULL;
    if (S < 1 || A < 1 || D < 1 || S > GRID_MAX_SIDE || A > GRID_MAX_SIDE) {
        PyErr_Format(PyExc_ValueError, "grid_spectrum: sizes must be positive and the grid sides at most %d",
                     GRID_MAX_SIDE);
        return NULL;
    }
    const Py_ssize_t A2 = A / 2 + 1, S2 = S / 2 + 1;
    const Py_ssize_t need[N_BUF] = {S * A * D * 4, S * A2 * 2 * D * 4, S * A2 * D * 8, S * A * 4, A2 * A * 4,
                                    A2 * A * 4, S2 * S * 4, S2 * S * 4};
    Py_buffer views[N_BUF];
    const int held = acquire_views(objs, views, N_BUF, need, codes, writable, names, OUT + 1, "grid_spectrum");
    if (held == N_BUF) {
        Py_BEGIN_ALLOW_THREADS
        grid_spectrum_run(views[X].buf, views[WIN].buf, views[COS_A].buf, views[SIN_A].buf, views[COS_S].buf,
                          views[SIN_S].buf, views[SCRATCH].buf, views[OUT].buf, S, A, D);
        Py_END_ALLOW_THREADS
    }
    release_views(views, held < 0 ? N_BUF : held);
    if (held != N_BUF)
        return NULL;
    Py_RETURN_NONE;
}

/* Sum of a GridVec's lanes, in a fixed order. */
static ALWAYS_INLINE float grid_lanes_sum(GridVec v)
{
    return (v[0] + v[1]) + (v[2] + v[3]);
}

/* sum_d |x_d|^2 of n complex values (2n floats): lane-parallel partial sums, then the tail. */
static ALWAYS_INLINE float grid_energy(const float *restrict x, Py_ssize_t n)
{
    const Py_ssize_t floats = 2 * n, blocked = floats - floats % GRID_BLOCK;
    GridVec acc = {0};
    for (Py_ssize_t f = 0; f < blocked; f += GRID_BLOCK) {
        const GridVec v = *(const GridVec *)(x + f);
        acc += v * v;
    }
    float energy = grid_lanes_sum(acc);
    for (Py_ssize_t f = blocked; f < floats; f++)
        energy += x[f] * x[f];
    return energy;
}

/* The size filter's DSST update and response over M grid frequencies of D channels (the specifications are
 * size_filter.dsst_train_reference and dsst_response_spectrum_reference):
 *   train:    numerator = (1 - rate) numerator + rate y conj(x), denominator = (1 - rate) denominator + rate
 *             sum_d |x|^2 (first: numerator = y conj(x), denominator = sum_d |x|^2);
 *   response: out[m] = sum_d numerator[m][d] x[m][d] / (denominator[m] + lambda). */
static HOT_LOOP_CLONES void grid_train_run(const float *restrict label, const float *restrict x,
                                           float *restrict num, float *restrict den, float rate, int first,
                                           Py_ssize_t M, Py_ssize_t D)
{
    const float keep = 1.0f - rate;
    for (Py_ssize_t m = 0; m < M; m++) {
        const float yr = label[2 * m], yi = label[2 * m + 1];
        const float *xm = x + 2 * m * D;
        float *nm = num + 2 * m * D;
        if (first) {
            for (Py_ssize_t d = 0; d < D; d++) {
                const float xr = xm[2 * d], xi = xm[2 * d + 1];
                nm[2 * d] = yr * xr + yi * xi;
                nm[2 * d + 1] = yi * xr - yr * xi;
            }
            den[m] = grid_energy(xm, D);
        } else {
            for (Py_ssize_t d = 0; d < D; d++) {
                const float xr = xm[2 * d], xi = xm[2 * d + 1];
                nm[2 * d] = keep * nm[2 * d] + rate * (yr * xr + yi * xi);
                nm[2 * d + 1] = keep * nm[2 * d + 1] + rate * (yi * xr - yr * xi);
            }
            den[m] = keep * den[m] + rate * grid_energy(xm, D);
        }
    }
}

/* (1, 0, 3, 2, ...): a GridVec of interleaved complex values with each value's real and imaginary parts swapped. */
static ALWAYS_INLINE GridVec grid_swap_pairs(GridVec v)
{
#if defined(__clang__)
    return __builtin_shufflevector(v, v, 1, 0, 3, 2);
#else
    typedef int GridMask __attribute__((vector_size(16)));
    return __builtin_shuffle(v, (GridMask){1, 0, 3, 2});
#endif
}

static HOT_LOOP_CLONES void grid_response_run(const float *restrict num, const float *restrict x,
                                              const float *restrict den, float lam, float *restrict out,
                                              Py_ssize_t M, Py_ssize_t D)
{
    const Py_ssize_t floats = 2 * D, blocked = floats - floats % GRID_BLOCK;
    for (Py_ssize_t m = 0; m < M; m++) {
        const float *xm = x + 2 * m * D, *nm = num + 2 * m * D;
        /* same = (nr xr, ni xi, ...), crossed = (nr xi, ni xr, ...): re = sum even(same) - odd(same),
         * im = sum of crossed. */
        GridVec same = {0}, crossed = {0};
        for (Py_ssize_t f = 0; f < blocked; f += GRID_BLOCK) {
            const GridVec n = *(const GridVec *)(nm + f), v = *(const GridVec *)(xm + f);
            same += n * v;
            crossed += n * grid_swap_pairs(v);
        }
        float re = (same[0] - same[1]) + (same[2] - same[3]);
        float im = grid_lanes_sum(crossed);
        for (Py_ssize_t f = blocked; f < floats; f += 2) {
            re += nm[f] * xm[f] - nm[f + 1] * xm[f + 1];
            im += nm[f] * xm[f + 1] + nm[f + 1] * xm[f];
        }
        const float scale = 1.0f / (den[m] + lam);
        out[2 * m] = re * scale;
        out[2 * m + 1] = im * scale;
    }
}

/* grid_train(label, x, numerator, denominator, rate, first, M, D): label (M) and x, numerator (M, D) complex64,
 * denominator (M) float32; numerator and denominator updated in place. */
static PyObject *grid_train(PyObject *self, PyObject *args)
{
    (void)self;
    enum { X, NUMERATOR, LABEL, DENOMINATOR, N_BUF };
    static const char *const names[N_BUF] = {"x", "numerator", "label", "denominator"};
    static const char *const codes[N_BUF] = {"Zf", "Zf", "Zf", "f"};
    static const int writable[N_BUF] = {0, 1, 0, 1};
    PyObject *objs[N_BUF];
    double rate;
    int first;
    Py_ssize_t M, D;
    if (!PyArg_ParseTuple(args, "OOOOdpnn", &objs[LABEL], &objs[X], &objs[NUMERATOR], &objs[DENOMINATOR], &rate,
                          &first, &M, &D))
        return NULL;
    if (M < 1 || D < 1) {
        PyErr_SetString(PyExc_ValueError, "grid_train: sizes must be positive");
        return NULL;
    }
    const Py_ssize_t need[N_BUF] = {M * D * 8, M * D * 8, M * 8, M * 4};
    Py_buffer views[N_BUF];
    const int held = acquire_views(objs, views, N_BUF, need, codes, writable, names, NUMERATOR + 1, "grid_train");
    if (held == N_BUF) {
        Py_BEGIN_ALLOW_THREADS
        grid_train_run(views[LABEL].buf, views[X].buf, views[NUMERATOR].buf, views[DENOMINATOR].buf, (float)rate,
                       first, M, D);
        Py_END_ALLOW_THREADS
    }
    release_views(views, held < 0 ? N_BUF : held);
    if (held != N_BUF)
        return NULL;
    Py_RETURN_NONE;
}

/* grid_response(numerator, x, denominator, lam, out, M, D): out (M) complex64. */
static PyObject *grid_response(PyObject *self, PyObject *args)
{
    (void)self;
    enum { NUMERATOR, X, DENOMINATOR, OUT, N_BUF };
    static const char *const names[N_BUF] = {"numerator", "x", "denominator", "out"};
    static const char *const codes[N_BUF] = {"Zf", "Zf", "f", "Zf"};
    static const int writable[N_BUF] = {0, 0, 0, 1};
    PyObject *objs[N_BUF];
    double lam;
    Py_ssize_t M, D;
    if (!PyArg_ParseTuple(args, "OOOdOnn", &objs[NUMERATOR], &objs[X], &objs[DENOMINATOR], &lam, &objs[OUT], &M, &D))
        return NULL;
    if (M < 1 || D < 1) {
        PyErr_SetString(PyExc_ValueError, "grid_response: sizes must be positive");
        return NULL;
    }
    const Py_ssize_t need[N_BUF] = {M * D * 8, M * D * 8, M * 4, M * 8};
    Py_buffer views[N_BUF];
    const int held = acquire_views(objs, views, N_BUF, need, codes, writable, names, 0, "grid_response");
    if (held == N_BUF) {
        Py_BEGIN_ALLOW_THREADS
        grid_response_run(views[NUMERATOR].buf, views[X].buf, views[DENOMINATOR].buf, (float)lam, views[OUT].buf, M,
                          D);
        Py_END_ALLOW_THREADS
    }
    release_views(views, held < 0 ? N_BUF : held);
    if (held != N_BUF)
        return NULL;
    Py_RETURN_NONE;
}

/* ---- The decision filter's windows (jsar/redetect/memory.py): cosine window and response spectra ---- */

/* window_channels_last(x, window, out, N, P, C): out[n, p, c] = x[n, p, c] * window[p] (float32; one product each,
 * so the numbers of numpy's broadcast multiply). */
static void window_channels_last_run(const float *restrict x, const float *restrict window, float *restrict out,
                                     Py_ssize_t N, Py_ssize_t P, Py_ssize_t C)
{
    for (Py_ssize_t n = 0; n < N; n++)
        for (Py_ssize_t p = 0; p < P; p++) {
            const float w = window[p];
            const float *restrict src = x + (n * P + p) * C;
            float *restrict dst = out + (n * P + p) * C;
            for (Py_ssize_t c = 0; c < C; c++)
                dst[c] = src[c] * w;
        }
}

static PyObject *window_channels_last(PyObject *self, PyObject *args)
{
    (void)self;
    enum { X, WIN, OUT, N_BUF };
    static const char *const names[N_BUF] = {"x", "window", "out"};
    static const char *const codes[N_BUF] = {"f", "f", "f"};
    static const int writable[N_BUF] = {0, 0, 1};
    PyObject *objs[N_BUF];
    Py_ssize_t N, P, C;
    if (!PyArg_ParseTuple(args, "OOOnnn", &objs[X], &objs[WIN], &objs[OUT], &N, &P, &C))
        return NULL;
    if (N < 0 || P < 0 || C < 0) {
        PyErr_SetString(PyExc_ValueError, "window_channels_last: sizes must be non-negative");
        return NULL;
    }
    const Py_ssize_t need[N_BUF] = {N * P * C * 4, P * 4, N * P * C * 4};
    Py_buffer views[N_BUF];
    const int held = acquire_views(objs, views, N_BUF, need, codes, writable, names, 0, "window_channels_last");
    if (held == N_BUF) {
        Py_BEGIN_ALLOW_THREADS
        window_channels_last_run(views[X].buf, views[WIN].buf, views[OUT].buf, N, P, C);
        Py_END_ALLOW_THREADS
    }
    release_views(views, held < 0 ? N_BUF : held);
    if (held != N_BUF)
        return NULL;
    Py_RETURN_NONE;
}

/* response_spectra(filter_f, spectra, out, M, P, C): out[m, p] = sum over c of conj(filter_f[c, p]) * spectra[m, p, c]
 * (complex64 as float pairs), summed in channel order in float, each product as (a_re x_re - a_im x_im, a_re x_im +
 * a_im x_re) with a = conj(f), never fused, then added to a zero: the numbers of numpy's
 * einsum("hwc,mhwc->mhw", conj(filter) channels last, spectra), which the tests check to the bit. */
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("fp-contract=off")))
#endif
static void response_spectra_run(const float *restrict f, const float *restrict x, float *restrict out, Py_ssize_t M,
                                 Py_ssize_t P, Py_ssize_t C)
{
    for (Py_ssize_t m = 0; m < M; m++)
        for (Py_ssize_t p = 0; p < P; p++) {
            const float *restrict xs = x + 2 * (m * P + p) * C;
            float acc_re = 0.0f, acc_im = 0.0f;
            for (Py_ssize_t c = 0; c < C; c++) {
                const float a_re = f[2 * (c * P + p)], a_im = -f[2 * (c * P + p) + 1];
                const float x_re = xs[2 * c], x_im = xs[2 * c + 1];
                const float re = a_re * x_re - a_im * x_im;
                const float im = a_re * x_im + a_im * x_re;
                acc_re += re;
                acc_im += im;
            }
            out[2 * (m * P + p)] = 0.0f + acc_re;
            out[2 * (m * P + p) + 1] = 0.0f + acc_im;
        }
}

static PyObject *response_spectra(PyObject *self, PyObject *args)
{
    (void)self;
    enum { F, X, OUT, N_BUF };
    static const char *const names[N_BUF] = {"filter_f", "spectra", "out"};
    static const char *const codes[N_BUF] = {"Zf", "Zf", "Zf"};
    static const int writable[N_BUF] = {0, 0, 1};
    PyObject *objs[N_BUF];
    Py_ssize_t M, P, C;
    if (!PyArg_ParseTuple(args, "OOOnnn", &objs[F], &objs[X], &objs[OUT], &M, &P, &C))
        return NULL;
    if (M < 0 || P < 0 || C < 0) {
        PyErr_SetString(PyExc_ValueError, "response_spectra: sizes must be non-negative");
        return NULL;
    }
    const Py_ssize_t need[N_BUF] = {C * P * 8, M * P * C * 8, M * P * 8};
    Py_buffer views[N_BUF];
    const int held = acquire_views(objs, views, N_BUF, need, codes, writable, names, N_BUF, "response_spectra");
    if (held == N_BUF) {
        Py_BEGIN_ALLOW_THREADS
        response_spectra_run(views[F].buf, views[X].buf, views[OUT].buf, M, P, C);
        Py_END_ALLOW_THREADS
    }
    release_views(views, held < 0 ? N_BUF : held);
    if (held != N_BUF)
        return NULL;
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"resample", resample, METH_VARARGS, "Separable sparse resampling of uint8 regions (see patches.py)."},
    {"resample_reference", resample_reference, METH_VARARGS,
     "resample through abi 5's loops, the bit-exact specification of resample."},
    {"fhog", fhog, METH_VARARGS, "fHOG, 31 channels per cell (see fhog.py)."},
    {"fhog_reference", fhog_reference, METH_VARARGS, "fhog through abi 5's loops, the bit-exact specification of fhog."},
    {"colour_cells", colour_cells, METH_VARARGS, "Cell means of colour-table rows of BGR pixels (see colour.py)."},
    {"colour_cells_reference", colour_cells_reference, METH_VARARGS,
     "colour_cells through abi 5's loops, the bit-exact specification of colour_cells."},
    {"strcf_f_step", strcf_f_step, METH_VARARGS, "One STRCF ADMM iteration's element-wise work (see dcf.admm_solve)."},
    {"grid_spectrum", grid_spectrum, METH_VARARGS, "The size filter's half spectrum over its grid (see size_filter.py)."},
    {"grid_train", grid_train, METH_VARARGS, "The size filter's DSST update (see size_filter.py)."},
    {"grid_response", grid_response, METH_VARARGS, "The size filter's response spectrum (see size_filter.py)."},
    {"window_channels_last", window_channels_last, METH_VARARGS,
     "Channels-last feature windows times a cosine window (see dcf.py)."},
    {"response_spectra", response_spectra, METH_VARARGS, "Windows' response spectra under one filter (see dcf.py)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kernels", "Compiled hot loops of jsar.features.", -1, methods,
                                    NULL, NULL, NULL, NULL};

/* Bumped whenever a signature or a convention changes: jsar/features/_native.py refuses a stale build. */
#define KERNELS_ABI 8

PyMODINIT_FUNC PyInit__kernels(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m && PyModule_AddIntConstant(m, "abi", KERNELS_ABI) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
