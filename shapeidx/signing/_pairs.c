/*
 * The pair pass of the signature in one compiled loop: for every pair i < j of sample
 * points, the distance, the entering/leaving test at both ends and, where the ends agree,
 * Embree's occlusion query of the shifted segment (shapeidx/signing/classify.py says why
 * each step is what it is). The numpy version makes a dozen passes over 523,776 pairs and
 * gathers two (n, 3) arrays of ray ends; this makes one, in cache, and hands Embree rays
 * in packets of 16 that share their origin.
 *
 * Embree is the library the embreex wheel ships (libembree4); it is opened with dlopen by
 * the path Python gives, so nothing here needs Embree's headers or links against it. The
 * few declarations below are Embree 4's public API (rtcore_*.h), written out.
 *
 * Every floating-point step is the one numpy takes, in the same order and precision
 * (float32 rises, float64 distances), so the classes are those of the numpy path bit for
 * bit; tests/test_compiled_pairs.py compares them on real parts.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <dlfcn.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

/* ---- Embree 4's API, as far as it is used here ---- */
typedef void *RTCDevice;
typedef void *RTCScene;
typedef void *RTCGeometry;
enum { RTC_GEOMETRY_TYPE_TRIANGLE = 0 };
enum { RTC_BUFFER_TYPE_INDEX = 0, RTC_BUFFER_TYPE_VERTEX = 1 };
enum { RTC_FORMAT_UINT3 = 0x5003, RTC_FORMAT_FLOAT3 = 0x9003 };

typedef struct __attribute__((aligned(16))) {
    float org_x, org_y, org_z, tnear;
    float dir_x, dir_y, dir_z, time;
    float tfar;
    unsigned int mask, id, flags;
} RTCRay;

typedef struct __attribute__((aligned(64))) {
    float org_x[16], org_y[16], org_z[16], tnear[16];
    float dir_x[16], dir_y[16], dir_z[16], time[16];
    float tfar[16];
    unsigned int mask[16], id[16], flags[16];
} RTCRay16;

static struct {
    int loaded;
    RTCDevice (*NewDevice)(const char *);
    int (*GetDeviceError)(RTCDevice);
    RTCScene (*NewScene)(RTCDevice);
    void (*ReleaseScene)(RTCScene);
    RTCGeometry (*NewGeometry)(RTCDevice, int);
    void (*SetSharedGeometryBuffer)(RTCGeometry, int, unsigned, int, const void *, size_t, size_t, size_t);
    void (*CommitGeometry)(RTCGeometry);
    unsigned (*AttachGeometry)(RTCScene, RTCGeometry);
    void (*ReleaseGeometry)(RTCGeometry);
    void (*CommitScene)(RTCScene);
    void (*SetSceneFlags)(RTCScene, int);
    void (*Occluded1)(RTCScene, RTCRay *, void *);
    void (*Occluded16)(const int *, RTCScene, RTCRay16 *, void *);
    RTCDevice device;
} embree;

#define BIND(field, name)                                                           \
    if (!(*(void **)&embree.field = dlsym(handle, name))) {                         \
        PyErr_Format(PyExc_ImportError, "%s has no %s", path, name);                \
        return NULL;                                                                \
    }

/* open_embree(path, config): load libembree4 and make the process's one device. */
static PyObject *open_embree(PyObject *self, PyObject *args) {
    const char *path, *config;
    if (!PyArg_ParseTuple(args, "ss", &path, &config)) return NULL;
    if (embree.loaded) Py_RETURN_NONE;
    void *handle = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!handle) {
        PyErr_Format(PyExc_ImportError, "cannot open %s: %s", path, dlerror());
        return NULL;
    }
    BIND(NewDevice, "rtcNewDevice") BIND(GetDeviceError, "rtcGetDeviceError")
    BIND(NewScene, "rtcNewScene") BIND(ReleaseScene, "rtcReleaseScene")
    BIND(NewGeometry, "rtcNewGeometry") BIND(SetSharedGeometryBuffer, "rtcSetSharedGeometryBuffer")
    BIND(CommitGeometry, "rtcCommitGeometry") BIND(AttachGeometry, "rtcAttachGeometry")
    BIND(ReleaseGeometry, "rtcReleaseGeometry") BIND(CommitScene, "rtcCommitScene")
    BIND(SetSceneFlags, "rtcSetSceneFlags")
    BIND(Occluded1, "rtcOccluded1") BIND(Occluded16, "rtcOccluded16")
    embree.device = embree.NewDevice(config[0] ? config : NULL);
    if (!embree.device) {
        PyErr_Format(PyExc_RuntimeError, "Embree could not start a device (config \"%s\")", config);
        return NULL;
    }
    embree.loaded = 1;
    Py_RETURN_NONE;
}

/* ---- Scene: triangles Embree reads in place (no copy), kept alive with the scene ---- */
typedef struct {
    PyObject_HEAD
    RTCScene scene;
    Py_buffer vertices, faces; /* float32 (n, 3) with one float of padding; uint32 (k, 3) */
} Scene;

static void Scene_dealloc(Scene *s) {
    if (s->scene) embree.ReleaseScene(s->scene);
    if (s->vertices.obj) PyBuffer_Release(&s->vertices);
    if (s->faces.obj) PyBuffer_Release(&s->faces);
    Py_TYPE(s)->tp_free((PyObject *)s);
}

/* Does a buffer hold items of this kind ('f' float, 'i' signed or 'u' unsigned integer) and size? */
static int buffer_is(const Py_buffer *b, char kind, Py_ssize_t itemsize) {
    if (b->itemsize != itemsize) return 0;
    const char *f = b->format ? b->format : "B";
    while (*f == '<' || *f == '=' || *f == '@' || *f == '!' || *f == '>') f++;
    if (f[0] == 0 || f[1] != 0) return 0;
    switch (kind) {
    case 'f': return f[0] == 'f' || f[0] == 'd';
    case 'i': return f[0] == 'b' || f[0] == 'h' || f[0] == 'i' || f[0] == 'l' || f[0] == 'q';
    default: return f[0] == 'B' || f[0] == 'H' || f[0] == 'I' || f[0] == 'L' || f[0] == 'Q' || f[0] == '?';
    }
}

/* Buffers for a function's arguments, released together. */
typedef struct {
    Py_buffer b[8];
    int got;
} Buffers;

/* One letter per argument, as numpy's dtype.char: 'd' float64, 'f' float32, 'i' int32,
   'I' uint32, 'q' int64, 'B' uint8. Arguments from first_writable on are written to. */
static int buffers_get(Buffers *bs, PyObject **objects, const char *kinds, int first_writable) {
    int n = (int)strlen(kinds);
    for (bs->got = 0; bs->got < n; bs->got++) {
        int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (bs->got >= first_writable ? PyBUF_WRITABLE : 0);
        if (PyObject_GetBuffer(objects[bs->got], &bs->b[bs->got], flags) < 0) return -1;
        char kind = kinds[bs->got];
        int ok = kind == 'd' ? buffer_is(&bs->b[bs->got], 'f', 8) : kind == 'f' ? buffer_is(&bs->b[bs->got], 'f', 4)
               : kind == 'i' ? buffer_is(&bs->b[bs->got], 'i', 4) : kind == 'I' ? buffer_is(&bs->b[bs->got], 'u', 4)
               : kind == 'q' ? buffer_is(&bs->b[bs->got], 'i', 8) : buffer_is(&bs->b[bs->got], 'u', 1);
        if (!ok) {
            bs->got++;
            PyErr_Format(PyExc_ValueError, "argument %d has the wrong dtype", bs->got);
            return -1;
        }
    }
    return 0;
}

static void buffers_release(Buffers *bs) {
    for (int k = 0; k < bs->got; k++) PyBuffer_Release(&bs->b[k]);
}

static int Scene_init(Scene *s, PyObject *args, PyObject *kw) {
    PyObject *vertices, *faces;
    Py_ssize_t n_vertices, n_faces;
    int flags = 0;
    if (!PyArg_ParseTuple(args, "OnOn|i", &vertices, &n_vertices, &faces, &n_faces, &flags)) return -1;
    if (!embree.loaded) {
        PyErr_SetString(PyExc_RuntimeError, "open_embree() first");
        return -1;
    }
    if (s->scene || s->vertices.obj) { /* a second __init__ would pull the scene from under a query */
        PyErr_SetString(PyExc_TypeError, "a Scene is made once");
        return -1;
    }
    if (n_vertices < 0 || n_faces < 0 || n_vertices > UINT32_MAX || n_faces > PY_SSIZE_T_MAX / 12) {
        PyErr_SetString(PyExc_ValueError, "vertex or face count out of range");
        return -1;
    }
    Py_buffer v = {0}, f = {0};
    RTCScene scene = NULL;
    RTCGeometry g = NULL;
    if (PyObject_GetBuffer(vertices, &v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) goto fail;
    if (PyObject_GetBuffer(faces, &f, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) goto fail;
    /* Embree reads vertices with 16-byte loads: the buffer has one float past the last */
    if (!buffer_is(&v, 'f', 4) || !buffer_is(&f, 'u', 4) || v.len / 4 < 3 * n_vertices + 1 || f.len / 12 < n_faces) {
        PyErr_SetString(PyExc_ValueError, "Scene: float32 vertices (3n + 1) and uint32 faces (3k) wanted");
        goto fail;
    }
    const uint32_t *corner = f.buf;
    for (Py_ssize_t k = 0; k < 3 * n_faces; k++)
        if (corner[k] >= (uint64_t)n_vertices) {
            PyErr_SetString(PyExc_ValueError, "a face refers to a vertex that does not exist");
            goto fail;
        }
    embree.GetDeviceError(embree.device); /* forget an error of an earlier call */
    scene = embree.NewScene(embree.device);
    g = embree.NewGeometry(embree.device, RTC_GEOMETRY_TYPE_TRIANGLE);
    if (!scene || !g) {
        PyErr_SetString(PyExc_RuntimeError, "Embree could not make a scene");
        goto fail;
    }
    if (flags) embree.SetSceneFlags(scene, flags);
    embree.SetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, v.buf, 0, 3 * sizeof(float),
                                   (size_t)n_vertices);
    embree.SetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, f.buf, 0, 3 * sizeof(uint32_t),
                                   (size_t)n_faces);
    embree.CommitGeometry(g);
    embree.AttachGeometry(scene, g);
    embree.ReleaseGeometry(g); /* the scene holds it */
    g = NULL;
    Py_BEGIN_ALLOW_THREADS
    embree.CommitScene(scene);
    Py_END_ALLOW_THREADS
    int error = embree.GetDeviceError(embree.device);
    if (error) {
        PyErr_Format(PyExc_RuntimeError, "Embree error %d building the scene", error);
        goto fail;
    }
    /* only a committed scene is ever seen by the methods */
    s->vertices = v;
    s->faces = f;
    s->scene = scene;
    return 0;
fail:
    if (g) embree.ReleaseGeometry(g);
    if (scene) embree.ReleaseScene(scene);
    if (v.obj) PyBuffer_Release(&v);
    if (f.obj) PyBuffer_Release(&f);
    return -1;
}

static int scene_ready(Scene *s) {
    if (!s->scene) PyErr_SetString(PyExc_RuntimeError, "the Scene was not made (its __init__ did not run or failed)");
    return s->scene != NULL;
}

/* ---- the pair pass ---- */

/* Rays waiting to be sent, all from one origin (one shifted sample), up to 16. */
typedef struct {
    RTCRay16 rays;
    int valid[16];
    int64_t slot[16]; /* where each ray's pair's class goes */
    int count;
    unsigned char side; /* the class if the ray is clear: IN 0 or OUT 1 */
} Packet;

enum { CLASS_IN = 0, CLASS_OUT = 1, CLASS_MIXED = 2 };

static void packet_flush(RTCScene scene, Packet *p, unsigned char *classes) {
    if (!p->count) return;
    for (int k = p->count; k < 16; k++) p->valid[k] = 0;
    embree.Occluded16(p->valid, scene, &p->rays, NULL);
    for (int k = 0; k < p->count; k++)
        classes[p->slot[k]] = (p->rays.tfar[k] < 0) ? CLASS_MIXED : p->side; /* -inf: occluded */
    p->count = 0;
}

static void packet_start(Packet *p, const float *origin, unsigned char side) {
    p->side = side;
    p->count = 0;
    for (int k = 0; k < 16; k++) {
        p->rays.org_x[k] = origin[0];
        p->rays.org_y[k] = origin[1];
        p->rays.org_z[k] = origin[2];
        p->rays.tnear[k] = 0.0f;
        p->rays.time[k] = 0.0f;
        p->rays.mask[k] = 0xFFFFFFFFu;
        p->rays.id[k] = 0;
        p->rays.flags[k] = 0;
    }
}

static void packet_add(RTCScene scene, Packet *p, const float *origin, const float *end, int64_t slot,
                       unsigned char *classes) {
    int k = p->count;
    p->rays.dir_x[k] = end[0] - origin[0]; /* float32, as np.subtract(..., dtype=float32) */
    p->rays.dir_y[k] = end[1] - origin[1];
    p->rays.dir_z[k] = end[2] - origin[2];
    p->rays.tfar[k] = 1.0f; /* the direction spans the whole segment */
    p->valid[k] = -1;
    p->slot[k] = slot;
    if (++p->count == 16) packet_flush(scene, p, classes);
}

/*
 * Scene.classify(points, points32, normals32, own, shifted, tangent, scale, first_row,
 *                stop_row, distances_out, classes_out, packets)
 *
 * Rows first_row..stop_row-1 of the pairs i < j (in pdist order), written at their flat
 * positions into distances_out (float64, in the part's units: distance / scale) and
 * classes_out (uint8). points: (m, 3) float64, normalised; points32, normals32: the same
 * as float32; own[i] = points32[i] . normals32[i] (float32, numpy's); shifted: (2m, 3)
 * float32, inward copies then outward ones. packets=0 sends one ray at a time.
 */
static PyObject *Scene_classify(Scene *s, PyObject *args) {
    PyObject *o_points, *o_p32, *o_n32, *o_own, *o_shifted, *o_order, *o_dist, *o_classes;
    double tangent, scale;
    Py_ssize_t first_row, stop_row;
    int packets;
    if (!PyArg_ParseTuple(args, "OOOOOOddnnOOp", &o_points, &o_p32, &o_n32, &o_own, &o_shifted, &o_order, &tangent,
                          &scale, &first_row, &stop_row, &o_dist, &o_classes, &packets))
        return NULL;
    if (!scene_ready(s)) return NULL;
    PyObject *objects[8] = {o_points, o_p32, o_n32, o_own, o_shifted, o_order, o_dist, o_classes};
    Buffers bs;
    Py_buffer *b = bs.b;
    PyObject *result = NULL;
    if (buffers_get(&bs, objects, "dffffidB", 6) < 0) goto done;
    Py_ssize_t m = b[0].len / (Py_ssize_t)(3 * sizeof(double));
    int64_t pairs = (int64_t)m * (m - 1) / 2;
    if (b[1].len != (Py_ssize_t)(3 * m * sizeof(float)) || b[2].len != b[1].len ||
        b[3].len != (Py_ssize_t)(m * sizeof(float)) || b[4].len != 2 * b[1].len ||
        b[5].len != (Py_ssize_t)(m * sizeof(int32_t)) ||
        b[6].len != (Py_ssize_t)(pairs * sizeof(double)) || b[7].len != (Py_ssize_t)pairs ||
        first_row < 0 || stop_row > m || first_row > stop_row) {
        PyErr_SetString(PyExc_ValueError, "classify: arrays of the wrong size");
        goto done;
    }
    const double *pt = b[0].buf;
    const float *p32 = b[1].buf, *n32 = b[2].buf, *own = b[3].buf, *shifted = b[4].buf;
    const int32_t *order = b[5].buf;
    double *dist = b[6].buf;
    unsigned char *classes = b[7].buf;
    RTCScene scene = s->scene;
    /* every pair is written once only if order is a permutation of the points */
    unsigned char *seen = calloc(m ? m : 1, 1);
    if (!seen) {
        PyErr_NoMemory();
        goto done;
    }
    for (Py_ssize_t k = 0; k < m; k++) {
        if (order[k] < 0 || order[k] >= m || seen[order[k]]) {
            free(seen);
            PyErr_SetString(PyExc_ValueError, "classify: order is not a permutation of the points");
            goto done;
        }
        seen[order[k]] = 1;
    }
    free(seen);

    Packet *inward = aligned_alloc(64, sizeof(Packet)), *outward = aligned_alloc(64, sizeof(Packet));
    if (!inward || !outward) {
        free(inward);
        free(outward);
        PyErr_NoMemory();
        goto done;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = first_row; i < stop_row; i++) {
        /* pair (i, j) lies at row_start + j in pdist order */
        int64_t row_start = (int64_t)i * m - (int64_t)i * (i + 1) / 2 - (i + 1), slot;
        const float *pi = p32 + 3 * i, *ni = n32 + 3 * i;
        const float *in_origin = shifted + 3 * i, *out_origin = shifted + 3 * (m + i);
        if (packets) {
            packet_start(inward, in_origin, CLASS_IN);
            packet_start(outward, out_origin, CLASS_OUT);
        }
        /* the pairs (i, j > i) in `order` (points near each other are near in it), so that
           the rays of a packet run side by side; each goes to its own slot */
        for (Py_ssize_t k = 0; k < m; k++) {
            Py_ssize_t j = order[k];
            if (j <= i) continue;
            slot = row_start + j;
            const double *a = pt + 3 * i, *c = pt + 3 * j;
            double dx = a[0] - c[0], dy = a[1] - c[1], dz = a[2] - c[2];
            double d = sqrt(dx * dx + dy * dy + dz * dz); /* as scipy's pdist */
            dist[slot] = d / scale;
            float threshold = (float)(tangent * d);
            const float *pj = p32 + 3 * j, *nj = n32 + 3 * j;
            /* rise[i, j] = p_i . n_j - own_j, and rise[j, i]: numpy's order of operations */
            float rise = pi[0] * nj[0];
            rise += pi[1] * nj[1];
            rise += pi[2] * nj[2];
            rise -= own[j];
            float rise_back = ni[0] * pj[0];
            rise_back += ni[1] * pj[1];
            rise_back += ni[2] * pj[2];
            rise_back -= own[i];
            int leaves_second = rise > threshold, leaves_first = rise_back > threshold;
            if (leaves_first != leaves_second) {
                classes[slot] = CLASS_MIXED;
                continue;
            }
            const float *origin = leaves_first ? out_origin : in_origin;
            const float *end = shifted + 3 * (leaves_first ? m + j : j);
            if (packets) {
                packet_add(scene, leaves_first ? outward : inward, origin, end, slot, classes);
            } else {
                RTCRay ray = {origin[0], origin[1], origin[2], 0.0f,
                              end[0] - origin[0], end[1] - origin[1], end[2] - origin[2], 0.0f,
                              1.0f, 0xFFFFFFFFu, 0, 0};
                embree.Occluded1(scene, &ray, NULL);
                classes[slot] = ray.tfar < 0 ? CLASS_MIXED : (unsigned char)leaves_first;
            }
        }
        if (packets) {
            packet_flush(scene, inward, classes);
            packet_flush(scene, outward, classes);
        }
    }
    free(inward);
    free(outward);
    Py_END_ALLOW_THREADS
    result = Py_None;
    Py_INCREF(result);
done:
    buffers_release(&bs);
    return result;
}

/* Scene.blocked(origins, directions, out): occlusion of rays (float32 (n, 3) each, tfar 1). */
static PyObject *Scene_blocked(Scene *s, PyObject *args) {
    PyObject *o_org, *o_dir, *o_out;
    if (!PyArg_ParseTuple(args, "OOO", &o_org, &o_dir, &o_out)) return NULL;
    if (!scene_ready(s)) return NULL;
    PyObject *objects[3] = {o_org, o_dir, o_out};
    Buffers bs;
    PyObject *result = NULL;
    if (buffers_get(&bs, objects, "ffB", 2) < 0) goto done;
    Py_ssize_t n = bs.b[2].len;
    if (bs.b[0].len != (Py_ssize_t)(3 * n * sizeof(float)) || bs.b[1].len != bs.b[0].len) {
        PyErr_SetString(PyExc_ValueError, "blocked: arrays of the wrong size");
        goto done;
    }
    const float *o = bs.b[0].buf, *d = bs.b[1].buf;
    unsigned char *hit = bs.b[2].buf;
    RTCScene scene = s->scene;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t k = 0; k < n; k++) {
        RTCRay ray = {o[3 * k], o[3 * k + 1], o[3 * k + 2], 0.0f, d[3 * k], d[3 * k + 1], d[3 * k + 2], 0.0f,
                      1.0f, 0xFFFFFFFFu, 0, 0};
        embree.Occluded1(scene, &ray, NULL);
        hit[k] = ray.tfar < 0;
    }
    Py_END_ALLOW_THREADS
    result = Py_None;
    Py_INCREF(result);
done:
    buffers_release(&bs);
    return result;
}

/* ---- histograms of the pairs (shapeidx/signing/histogram.py, angles.py) ---- */

/*
 * class_sums(distances, classes, sums_out, sizes_out, largest_out): per class, the sum of
 * the distances (in pair order, as np.bincount(classes, weights=distances) adds them), the
 * pair count and the largest distance (0 for an empty class).
 */
static PyObject *class_sums(PyObject *self, PyObject *args) {
    PyObject *o[5];
    if (!PyArg_ParseTuple(args, "OOOOO", &o[0], &o[1], &o[2], &o[3], &o[4])) return NULL;
    Buffers bs;
    PyObject *result = NULL;
    if (buffers_get(&bs, o, "dBdqd", 2) < 0) goto done;
    Py_ssize_t n = bs.b[1].len;
    if (bs.b[0].len != (Py_ssize_t)(n * sizeof(double)) || bs.b[2].len != 3 * sizeof(double) ||
        bs.b[3].len != 3 * sizeof(int64_t) || bs.b[4].len != 3 * sizeof(double)) {
        PyErr_SetString(PyExc_ValueError, "class_sums: arrays of the wrong size");
        goto done;
    }
    const double *d = bs.b[0].buf;
    const unsigned char *c = bs.b[1].buf;
    double *sums = bs.b[2].buf, *largest = bs.b[4].buf;
    int64_t *sizes = bs.b[3].buf;
    for (int k = 0; k < 3; k++) sums[k] = 0, sizes[k] = 0, largest[k] = 0;
    for (Py_ssize_t k = 0; k < n; k++) {
        if (c[k] > 2) {
            PyErr_SetString(PyExc_ValueError, "class_sums: a class code above 2");
            goto done;
        }
        sums[c[k]] += d[k];
        sizes[c[k]]++;
        if (d[k] > largest[c[k]]) largest[c[k]] = d[k];
    }
    result = Py_None;
    Py_INCREF(result);
done:
    buffers_release(&bs);
    return result;
}

/*
 * bin_counts(distances, classes, width_all, widths, all_out, class_out): each pair counted
 * in its bin of the ALL histogram (int(d / width_all)) and of its class's
 * (int(d / widths[class]), into row `class` of class_out (3, bins)). A width of 0 (no pairs
 * or all at distance 0) puts every pair in bin 0, as dividing by 1 does in numpy's version.
 */
static PyObject *bin_counts(PyObject *self, PyObject *args) {
    PyObject *o[5];
    double width_all;
    if (!PyArg_ParseTuple(args, "OOdOOO", &o[0], &o[1], &width_all, &o[2], &o[3], &o[4])) return NULL;
    Buffers bs;
    PyObject *result = NULL;
    if (buffers_get(&bs, o, "dBdqq", 3) < 0) goto done;
    Py_ssize_t n = bs.b[1].len, bins_all = bs.b[3].len / sizeof(int64_t), bins = bs.b[4].len / (3 * sizeof(int64_t));
    if (bs.b[0].len != (Py_ssize_t)(n * sizeof(double)) || bs.b[2].len != 3 * sizeof(double)) {
        PyErr_SetString(PyExc_ValueError, "bin_counts: arrays of the wrong size");
        goto done;
    }
    const double *d = bs.b[0].buf, *widths = bs.b[2].buf;
    const unsigned char *c = bs.b[1].buf;
    int64_t *all = bs.b[3].buf, *per_class = bs.b[4].buf;
    double divide_all = width_all > 0 ? width_all : 1.0, divide[3];
    for (int k = 0; k < 3; k++) divide[k] = widths[k] > 0 ? widths[k] : 1.0;
    for (Py_ssize_t k = 0; k < n; k++) {
        int64_t a = (int64_t)(d[k] / divide_all), b = (int64_t)(d[k] / divide[c[k] > 2 ? 0 : c[k]]);
        if (c[k] > 2 || a < 0 || a >= bins_all || b < 0 || b >= bins) {
            PyErr_SetString(PyExc_ValueError, "bin_counts: a bin outside the arrays");
            goto done;
        }
        all[a]++;
        per_class[c[k] * bins + b]++;
    }
    result = Py_None;
    Py_INCREF(result);
done:
    buffers_release(&bs);
    return result;
}

/*
 * angle_counts(normals, classes, cell_bins, counts_out, near_cos_out, near_class_out):
 * the cosine of every pair's normals (float64, numpy's order), its bin from the table over
 * len(cell_bins) cells of [-1, 1], counted per class into counts_out (3, bins); a pair whose
 * cell a bin edge crosses (table value -1) is written out instead, for numpy to bin by
 * arccos. Returns how many were written out.
 */
static PyObject *angle_counts(PyObject *self, PyObject *args) {
    PyObject *o[6];
    if (!PyArg_ParseTuple(args, "OOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5])) return NULL;
    Buffers bs;
    PyObject *result = NULL;
    if (buffers_get(&bs, o, "dBqqdB", 3) < 0) goto done;
    Py_ssize_t m = bs.b[0].len / (Py_ssize_t)(3 * sizeof(double)), pairs = (Py_ssize_t)m * (m - 1) / 2;
    Py_ssize_t cells = bs.b[2].len / sizeof(int64_t), bins = bs.b[3].len / (3 * sizeof(int64_t));
    if (bs.b[1].len != pairs || bs.b[4].len != (Py_ssize_t)(pairs * sizeof(double)) || bs.b[5].len != pairs ||
        cells < 1 || (cells & (cells - 1))) {
        PyErr_SetString(PyExc_ValueError, "angle_counts: arrays of the wrong size");
        goto done;
    }
    const double *n = bs.b[0].buf;
    const unsigned char *c = bs.b[1].buf;
    const int64_t *table = bs.b[2].buf;
    int64_t *counts = bs.b[3].buf;
    double *near_cos = bs.b[4].buf;
    unsigned char *near_class = bs.b[5].buf;
    for (Py_ssize_t k = 0; k < cells; k++)
        if (table[k] < -1 || table[k] >= bins) {
            PyErr_SetString(PyExc_ValueError, "angle_counts: a table bin outside the counts");
            goto done;
        }
    Py_ssize_t near = 0, slot = 0;
    double half = (double)cells / 2; /* a power of two: exact scaling, as numpy's */
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < m && !bad; i++) {
        const double *ni = n + 3 * i;
        for (Py_ssize_t j = i + 1; j < m; j++, slot++) {
            const double *nj = n + 3 * j;
            double cos = ni[0] * nj[0];
            cos += ni[1] * nj[1];
            cos += ni[2] * nj[2];
            double scaled = (cos + 1.0) * half;
            /* numpy's astype(intp) then clip: NaN, infinities and values past 2^63 become
               INT64_MIN, so cell 0; other values truncate, then clip to 0..cells-1 */
            Py_ssize_t cell = !(scaled > -9223372036854775808.0 && scaled < 9223372036854775808.0) ? 0
                              : scaled >= cells ? cells - 1 : (scaled > 0 ? (Py_ssize_t)scaled : 0);
            int64_t bin = table[cell];
            unsigned char code = c[slot];
            if (code > 2) {
                bad = 1;
                break;
            }
            if (bin < 0) {
                near_cos[near] = cos;
                near_class[near++] = code;
            } else {
                counts[code * bins + bin]++;
            }
        }
    }
    Py_END_ALLOW_THREADS
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "angle_counts: a class code above 2");
        goto done;
    }
    result = PyLong_FromSsize_t(near);
done:
    buffers_release(&bs);
    return result;
}

static PyMethodDef Scene_methods[] = {
    {"classify", (PyCFunction)Scene_classify, METH_VARARGS, "Distances and classes of rows of the pairs."},
    {"blocked", (PyCFunction)Scene_blocked, METH_VARARGS, "Occlusion of segments, one ray each."},
    {NULL}};

static PyTypeObject SceneType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "shapeidx.signing._pairs.Scene",
    .tp_basicsize = sizeof(Scene),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Scene(vertices, n_vertices, faces, n_faces): Embree triangles read in place.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Scene_init,
    .tp_dealloc = (destructor)Scene_dealloc,
    .tp_methods = Scene_methods,
};

static PyMethodDef module_methods[] = {
    {"open_embree", open_embree, METH_VARARGS, "open_embree(path, config): load libembree4, start a device."},
    {"class_sums", class_sums, METH_VARARGS, "Per class: distance sums, pair counts and largest distances."},
    {"bin_counts", bin_counts, METH_VARARGS, "Pairs per D2 bin, of all and per class."},
    {"angle_counts", angle_counts, METH_VARARGS, "Pairs per normal-angle bin per class, near-edge pairs written out."},
    {NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_pairs", "The signature's pair pass, compiled.", -1,
                                    module_methods};

PyMODINIT_FUNC PyInit__pairs(void) {
    if (PyType_Ready(&SceneType) < 0) return NULL;
    PyObject *m = PyModule_Create(&module);
    if (!m) return NULL;
    Py_INCREF(&SceneType);
    if (PyModule_AddObject(m, "Scene", (PyObject *)&SceneType) < 0) {
        Py_DECREF(&SceneType);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
