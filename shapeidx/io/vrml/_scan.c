/* Fast path of the VRML reader for flat VRML 2.0 files (what KiCad and most CAD
 * exporters write): top-level Shapes whose geometry is an IndexedFaceSet over a
 * Coordinate node, DEF/USE anywhere, any other node read generically and ignored.
 *
 * scan(data, max_triangles, max_visits) reads the whole file in one pass and returns
 * the finished mesh as three bytearrays (vertices float64, face sizes int64, face
 * indices int64) plus the counts the limits are checked on, or None.
 *
 * None means "not sure": anything this scanner does not know exactly how the Python
 * reader (lexer.py, parser.py, scene.py) would treat -- a string, a PROTO, a comment
 * inside brackets, a hexadecimal number, a group node, an out-of-range index, a
 * warning of any kind, an error of any kind -- makes it give up, and the Python
 * reader runs instead, with its own messages. So this file only has to be right about
 * the files it accepts, and for those it must give bit for bit what the Python reader
 * gives.
 *
 * Hostile input: every read is bounded by the end of the buffer; nesting is limited;
 * DEF names are found through a hash table; each distinct face set is split once
 * however often it is USEd; the counts are checked against the limits before any
 * output is allocated. Plain CPython C API, no numpy.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define MAX_DEPTH 100 /* below parser.MAX_NESTING (120): deeper files go to Python */

enum { K_OTHER, K_KNOWN, K_SHAPE, K_IFS, K_COORD };
enum { V_ABSENT, V_NODE, V_NUMBERS, V_BOOL, V_NULL };

typedef struct {
    int kind;
    int64_t a, b; /* NODE: a = node; NUMBERS: a = first, b = count; BOOL: a */
} Value;

typedef struct {
    int kind;
    Value f[4]; /* the fields the scene reads; f[0] unused (other fields) */
    int split;  /* IndexedFaceSet: 0 not yet, 1 done */
    int copied; /* Coordinate: its points are in the output */
    int64_t triangles, poly_start, poly_count, corner_start, corner_count;
    int64_t vertex_offset; /* Coordinate: first vertex in the output, -1 not placed */
} Node;

typedef struct {
    const unsigned char *name;
    Py_ssize_t len;
    int64_t node; /* -1: empty slot */
} Def;

typedef struct {
    const unsigned char *p, *end;
    int depth;
    Node *nodes;
    size_t n_nodes, cap_nodes;
    double *nums;
    size_t n_nums, cap_nums;
    int64_t *top;
    size_t n_top, cap_top;
    int64_t *sizes, *corners; /* split face sets (reached ones only) */
    size_t n_sizes, cap_sizes, n_corners, cap_corners;
    Def *defs;
    size_t n_defs, cap_defs;
} Scan;

/* Grow *buf (of *cap items of size item) to hold at least need items. 0 or -1. */
static int
grow(void **buf, size_t *cap, size_t need, size_t item)
{
    size_t new_cap;
    void *moved;
    if (need <= *cap)
        return 0;
    new_cap = *cap ? *cap : 64;
    while (new_cap < need) {
        if (new_cap > ((size_t)PY_SSIZE_T_MAX / item) / 2)
            return -1;
        new_cap *= 2;
    }
    moved = PyMem_Realloc(*buf, new_cap * item);
    if (moved == NULL)
        return -1;
    *buf = moved;
    *cap = new_cap;
    return 0;
}

#define PUSH(s, arr, n, cap, value)                                                      \
    (grow((void **)&(s)->arr, &(s)->cap, (s)->n + 1, sizeof(*(s)->arr)) < 0             \
         ? -1                                                                            \
         : ((s)->arr[(s)->n++] = (value), 0))

/* -- characters (the lexer's classes, narrowed: what is not here makes us give up) -- */

static int
is_space(unsigned char c) /* bytes.split() and \s: space \t \n \v \f \r; and ',' */
{
    return c == ' ' || c == ',' || (c >= '\t' && c <= '\r');
}

static int
is_name_start(unsigned char c) /* a subset of lexer._NAME_RE's first characters */
{
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '_';
}

static int
is_name_char(unsigned char c) /* a subset of lexer._NAME_RE's other characters */
{
    return is_name_start(c) || (c >= '0' && c <= '9') || c == '-';
}

static int
is_digit(unsigned char c)
{
    return c >= '0' && c <= '9';
}

/* Can a token end here, before this character, the same way for the lexer? */
static int
ends_token(const Scan *s, const unsigned char *q)
{
    unsigned char c;
    if (q >= s->end)
        return 1;
    c = *q;
    return is_space(c) || c == '{' || c == '}' || c == '[' || c == ']' || c == '#';
}

/* White space, commas and comments (lexer._SKIP_TEXT). */
static void
skip(Scan *s)
{
    const unsigned char *p = s->p, *end = s->end;
    while (p < end) {
        if (is_space(*p))
            p++;
        else if (*p == '#') {
            while (p < end && *p != '\n' && *p != '\r')
                p++;
        }
        else
            break;
    }
    s->p = p;
}

/* White space and commas only: inside brackets, where a comment makes us give up. */
static void
skip_in_array(Scan *s)
{
    const unsigned char *p = s->p, *end = s->end;
    while (p < end && is_space(*p))
        p++;
    s->p = p;
}

/* A name at s->p; its text in *name, *len. Keywords are refused by the callers. */
static int
read_name(Scan *s, const unsigned char **name, Py_ssize_t *len)
{
    const unsigned char *q = s->p;
    if (q >= s->end || !is_name_start(*q))
        return -1;
    while (q < s->end && is_name_char(*q))
        q++;
    if (!ends_token(s, q))
        return -1; /* e.g. a '(' or a UTF-8 byte the lexer would keep in the name */
    *name = s->p;
    *len = q - s->p;
    s->p = q;
    return 0;
}

static int
name_is(const unsigned char *name, Py_ssize_t len, const char *word)
{
    return (Py_ssize_t)strlen(word) == len && memcmp(name, word, len) == 0;
}

/* Words with a meaning of their own to parser.py: never taken as a field or type name. */
static const char *const KEYWORDS[] = {
    "DEF", "USE", "NULL", "TRUE", "FALSE", "IS", "PROTO", "EXTERNPROTO", "ROUTE", "TO",
    "field", "exposedField", "initializeOnly", "inputOutput", "eventIn", "eventOut",
    "inputOnly", "outputOnly", NULL,
};

static int
is_keyword(const unsigned char *name, Py_ssize_t len)
{
    const char *const *word;
    for (word = KEYWORDS; *word != NULL; word++)
        if (name_is(name, len, *word))
            return 1;
    return 0;
}

/* scene.V2_NO_GEOMETRY (a test checks that the two lists agree) */
static const char *const KNOWN_OTHER[] = {
    "IndexedLineSet", "PointSet", "Text", "Appearance", "Material", "ImageTexture",
    "PixelTexture", "MovieTexture", "TextureTransform", "TextureCoordinate", "Color",
    "Normal", "Coordinate", "FontStyle", "Viewpoint", "NavigationInfo", "Background",
    "Fog", "WorldInfo", "DirectionalLight", "PointLight", "SpotLight", "Sound",
    "AudioClip", "Script", "TimeSensor", "TouchSensor", "PlaneSensor", "CylinderSensor",
    "SphereSensor", "ProximitySensor", "VisibilitySensor", "ColorInterpolator",
    "CoordinateInterpolator", "NormalInterpolator", "OrientationInterpolator",
    "PositionInterpolator", "ScalarInterpolator", NULL,
};

static int
kind_of_type(const unsigned char *name, Py_ssize_t len)
{
    const char *const *word;
    if (name_is(name, len, "Shape"))
        return K_SHAPE;
    if (name_is(name, len, "IndexedFaceSet"))
        return K_IFS;
    if (name_is(name, len, "Coordinate"))
        return K_COORD;
    for (word = KNOWN_OTHER; *word != NULL; word++)
        if (name_is(name, len, *word))
            return K_KNOWN;
    return K_OTHER;
}

/* Which of Node.f a field goes to (0: a field the scene never reads). */
static int
field_slot(int kind, const unsigned char *name, Py_ssize_t len)
{
    switch (kind) {
    case K_SHAPE:
        return name_is(name, len, "geometry") ? 1 : 0;
    case K_IFS:
        if (name_is(name, len, "coord"))
            return 1;
        if (name_is(name, len, "coordIndex"))
            return 2;
        return name_is(name, len, "ccw") ? 3 : 0;
    case K_COORD:
        return name_is(name, len, "point") ? 1 : 0;
    }
    return 0;
}

/* -- numbers ---------------------------------------------------------------------------- */

static const double POW10[] = {
    1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
    1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
};

/* One number at s->p, in the lexer's decimal grammar
 * [+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?, followed by what ends a token; its value,
 * correctly rounded as Python's float() gives it, in *out.
 *
 * A mantissa of at most 15 digits with a power of ten up to 22 is one exact operand
 * times or divided by another, which IEEE arithmetic rounds correctly (Clinger's fast
 * path): KiCad's "0.261". Others go to PyOS_string_to_double (float()'s own parser).
 * Values that overflow or underflow are refused: numpy may read those differently. */
static int
read_number(Scan *s, double *out)
{
    const unsigned char *q = s->p, *end = s->end, *start = s->p;
    int negative = 0, digits = 0, significant = 0, exponent_digits = 0;
    uint64_t mantissa = 0;
    int64_t scale = 0, exponent = 0;
    double value;

    if (q < end && (*q == '+' || *q == '-'))
        negative = *q++ == '-';
    for (; q < end && is_digit(*q); q++, digits++) {
        if (significant || *q != '0') {
            if (significant < 19)
                mantissa = mantissa * 10 + (*q - '0');
            else
                scale++;
            significant++;
        }
    }
    if (q < end && *q == '.') {
        q++;
        for (; q < end && is_digit(*q); q++, digits++) {
            if (significant || *q != '0') {
                if (significant < 19) {
                    mantissa = mantissa * 10 + (*q - '0');
                    scale--;
                }
                significant++;
            }
            else
                scale--;
        }
    }
    if (digits == 0)
        return -1;
    if (q < end && (*q == 'e' || *q == 'E')) {
        const unsigned char *r = q + 1;
        int exponent_negative = 0;
        if (r < end && (*r == '+' || *r == '-'))
            exponent_negative = *r++ == '-';
        if (r < end && is_digit(*r)) {
            for (; r < end && is_digit(*r); r++, exponent_digits++)
                if (exponent < 100000)
                    exponent = exponent * 10 + (*r - '0');
            q = r;
            scale += exponent_negative ? -exponent : exponent;
        }
    }
    if (!ends_token(s, q))
        return -1; /* "1-2", "0x1f", "1e": tokens the lexer splits differently */
    if (mantissa == 0)
        value = 0.0;
    else if (significant <= 15 && scale >= -22 && scale <= 22)
        value = scale < 0 ? (double)mantissa / POW10[-scale] : (double)mantissa * POW10[scale];
    else {
        char *stop = NULL;
        if (q >= end || *q == '\0')
            return -1; /* not followed by a delimiter the C parser stops at */
        value = PyOS_string_to_double((const char *)start, &stop, NULL);
        if (value == -1.0 && PyErr_Occurred()) {
            PyErr_Clear();
            return -1;
        }
        if ((const unsigned char *)stop != q)
            return -1;
        value = fabs(value);
        if (!isfinite(value) || value < DBL_MIN)
            return -1; /* overflow, underflow or a denormal */
    }
    *out = negative ? -value : value;
    s->p = q;
    return 0;
}

/* Numbers starting at s->p, stored (store) or only checked: a '[' array, or numbers
 * written without brackets. */
static int
read_numbers(Scan *s, int bracketed, int store, Value *v)
{
    size_t first = s->n_nums;
    int64_t count = 0;
    double value;
    for (;;) {
        if (read_number(s, &value) < 0)
            return -1;
        if (store && PUSH(s, nums, n_nums, cap_nums, value) < 0)
            return -1;
        count++;
        if (bracketed) {
            skip_in_array(s);
            if (s->p >= s->end || *s->p == '#')
                return -1; /* unterminated, or a comment that may hold the ']' */
            if (*s->p == ']') {
                s->p++;
                break;
            }
        }
        else {
            skip(s);
            if (s->p >= s->end)
                break;
            if (!(is_digit(*s->p) || *s->p == '+' || *s->p == '-' || *s->p == '.'))
                break;
        }
    }
    v->kind = V_NUMBERS;
    v->a = (int64_t)first;
    v->b = count;
    return 0;
}

/* Does the text at q start a number for the lexer's array look-ahead [+-]?\.?\d ? */
static int
starts_number(const Scan *s, const unsigned char *q)
{
    if (q < s->end && (*q == '+' || *q == '-'))
        q++;
    if (q < s->end && *q == '.')
        q++;
    return q < s->end && is_digit(*q);
}

/* -- DEF names ---------------------------------------------------------------------------- */

static size_t
hash_name(const unsigned char *name, Py_ssize_t len)
{
    uint64_t h = 1469598103934665603ULL;
    Py_ssize_t i;
    for (i = 0; i < len; i++)
        h = (h ^ name[i]) * 1099511628211ULL;
    return (size_t)h;
}

static Def *
find_def(Scan *s, const unsigned char *name, Py_ssize_t len)
{
    size_t i;
    if (s->cap_defs == 0)
        return NULL;
    for (i = hash_name(name, len) & (s->cap_defs - 1);; i = (i + 1) & (s->cap_defs - 1)) {
        Def *d = &s->defs[i];
        if (d->node < 0 || (d->len == len && memcmp(d->name, name, len) == 0))
            return d;
    }
}

/* DEF name: the name now stands for node (a later DEF of the same name wins). */
static int
bind(Scan *s, const unsigned char *name, Py_ssize_t len, int64_t node)
{
    Def *d;
    if (2 * (s->n_defs + 1) > s->cap_defs) { /* keep the table at most half full */
        size_t cap = s->cap_defs ? 2 * s->cap_defs : 64, i;
        Def *old = s->defs, *table;
        size_t old_cap = s->cap_defs;
        if (cap > (size_t)PY_SSIZE_T_MAX / sizeof(Def))
            return -1;
        table = PyMem_Malloc(cap * sizeof(Def));
        if (table == NULL)
            return -1;
        for (i = 0; i < cap; i++)
            table[i].node = -1;
        s->defs = table;
        s->cap_defs = cap;
        for (i = 0; i < old_cap; i++)
            if (old[i].node >= 0)
                *find_def(s, old[i].name, old[i].len) = old[i];
        PyMem_Free(old);
    }
    d = find_def(s, name, len);
    if (d->node < 0)
        s->n_defs++;
    d->name = name;
    d->len = len;
    d->node = node;
    return 0;
}

/* -- nodes -------------------------------------------------------------------------------- */

static int read_node(Scan *s, const unsigned char *type, Py_ssize_t len, int64_t *out);

/* "DEF name Type {...}" after the DEF, or "USE name" after the USE: the node. */
static int
read_def(Scan *s, int64_t *out)
{
    const unsigned char *name, *type;
    Py_ssize_t name_len, type_len;
    skip(s);
    if (read_name(s, &name, &name_len) < 0 || is_keyword(name, name_len))
        return -1;
    skip(s);
    if (read_name(s, &type, &type_len) < 0 || is_keyword(type, type_len))
        return -1;
    if (read_node(s, type, type_len, out) < 0)
        return -1;
    return bind(s, name, name_len, *out);
}

static int
read_use(Scan *s, int64_t *out)
{
    const unsigned char *name;
    Py_ssize_t len;
    Def *d;
    skip(s);
    if (read_name(s, &name, &len) < 0 || is_keyword(name, len))
        return -1;
    d = find_def(s, name, len);
    if (d == NULL || d->node < 0)
        return -1; /* undefined: the Python reader warns */
    *out = d->node;
    return 0;
}

/* A field's value at s->p (after skip): numbers, TRUE/FALSE, NULL, or a node. */
static int
read_value(Scan *s, int store, Value *v)
{
    const unsigned char *name;
    Py_ssize_t len;
    unsigned char c;
    if (s->p >= s->end)
        return -1;
    c = *s->p;
    if (c == '[') {
        s->p++;
        skip_in_array(s);
        if (!starts_number(s, s->p))
            return -1; /* a list of nodes or strings, an empty list, a comment */
        return read_numbers(s, 1, store, v);
    }
    if (is_digit(c) || c == '+' || c == '-' || c == '.')
        return read_numbers(s, 0, store, v);
    if (read_name(s, &name, &len) < 0)
        return -1;
    if (name_is(name, len, "TRUE") || name_is(name, len, "FALSE")) {
        v->kind = V_BOOL;
        v->a = name[0] == 'T';
        return 0;
    }
    if (name_is(name, len, "NULL")) {
        v->kind = V_NULL;
        return 0;
    }
    v->kind = V_NODE;
    if (name_is(name, len, "USE"))
        return read_use(s, &v->a);
    if (name_is(name, len, "DEF"))
        return read_def(s, &v->a);
    if (is_keyword(name, len))
        return -1;
    return read_node(s, name, len, &v->a); /* refuses a word that is no node type */
}

/* The node whose type name was just read: its "{ fields }". */
static int
read_node(Scan *s, const unsigned char *type, Py_ssize_t len, int64_t *out)
{
    int64_t index = (int64_t)s->n_nodes;
    int kind = kind_of_type(type, len), i;
    Node node;
    skip(s);
    if (s->p >= s->end || *s->p != '{')
        return -1;
    s->p++;
    if (++s->depth > MAX_DEPTH)
        return -1;
    memset(&node, 0, sizeof(node));
    node.kind = kind;
    node.vertex_offset = -1;
    for (i = 0; i < 4; i++)
        node.f[i].kind = V_ABSENT;
    if (PUSH(s, nodes, n_nodes, cap_nodes, node) < 0)
        return -1;
    for (;;) {
        const unsigned char *name;
        Py_ssize_t name_len;
        Value value;
        int slot;
        skip(s);
        if (s->p >= s->end)
            return -1;
        if (*s->p == '}') {
            s->p++;
            break;
        }
        if (read_name(s, &name, &name_len) < 0 || is_keyword(name, name_len))
            return -1;
        skip(s);
        if (s->p < s->end && *s->p == '{')
            return -1; /* a VRML 1.0 child node */
        slot = field_slot(kind, name, name_len);
        if (read_value(s, slot != 0, &value) < 0)
            return -1;
        s->nodes[index].f[slot] = value; /* the last value of a field wins, as in a dict */
    }
    s->depth--;
    *out = index;
    return 0;
}

/* The top-level statements: nodes, DEF, USE, NULL. */
static int
read_file(Scan *s)
{
    for (;;) {
        const unsigned char *name;
        Py_ssize_t len;
        int64_t node;
        skip(s);
        if (s->p >= s->end)
            return 0;
        if (read_name(s, &name, &len) < 0)
            return -1;
        if (name_is(name, len, "NULL"))
            continue;
        if (name_is(name, len, "DEF")) {
            if (read_def(s, &node) < 0)
                return -1;
        }
        else if (name_is(name, len, "USE")) {
            if (read_use(s, &node) < 0)
                return -1;
        }
        else if (is_keyword(name, len) || read_node(s, name, len, &node) < 0)
            return -1;
        if (PUSH(s, top, n_top, cap_top, node) < 0)
            return -1;
    }
}

/* -- the scene ---------------------------------------------------------------------------- */

/* Split an IndexedFaceSet's coordIndex into polygons once (geometry.py's
 * face_sets_from_coord_indices for one array), refusing whatever that would drop or
 * report: fractions, indices out of range, polygons of one or two corners. */
static int
split_face_set(Scan *s, Node *ifs)
{
    const Value *coord = &ifs->f[1], *index = &ifs->f[2], *ccw = &ifs->f[3];
    const Node *points;
    int64_t point_count, i, polygon = 0;
    if (ifs->split)
        return 0;
    if (coord->kind != V_NODE || s->nodes[coord->a].kind != K_COORD)
        return -1;
    points = &s->nodes[coord->a];
    if (points->f[1].kind != V_NUMBERS || points->f[1].b % 3 != 0)
        return -1;
    if (ccw->kind != V_ABSENT && ccw->kind != V_BOOL)
        return -1;
    if (index->kind != V_NUMBERS && index->kind != V_ABSENT)
        return -1;
    point_count = points->f[1].b / 3;
    ifs->poly_start = (int64_t)s->n_sizes;
    ifs->corner_start = (int64_t)s->n_corners;
    if (index->kind == V_NUMBERS) {
        const double *values = s->nums + index->a;
        for (i = 0; i <= index->b; i++) {
            if (i == index->b || values[i] == -1.0) { /* the end of a polygon */
                if (polygon == 0)
                    continue; /* "-1 -1" or a final -1: no polygon, no note */
                if (polygon < 3)
                    return -1;
                if (PUSH(s, sizes, n_sizes, cap_sizes, polygon) < 0)
                    return -1;
                polygon = 0;
                continue;
            }
            if (!(values[i] >= 0.0 && values[i] < (double)point_count))
                return -1; /* out of range, or NaN */
            if ((double)(int64_t)values[i] != values[i])
                return -1; /* a fraction */
            if (PUSH(s, corners, n_corners, cap_corners, (int64_t)values[i]) < 0)
                return -1;
            polygon++;
        }
    }
    ifs->poly_count = (int64_t)s->n_sizes - ifs->poly_start;
    ifs->corner_count = (int64_t)s->n_corners - ifs->corner_start;
    ifs->triangles = ifs->corner_count - 2 * ifs->poly_count;
    ifs->split = 1;
    return 0;
}

/* The IndexedFaceSet a top-level node draws (NULL: none), or -1 to give up. */
static int
face_set_of(Scan *s, const Node *node, Node **ifs)
{
    *ifs = NULL;
    if (node->kind == K_KNOWN || node->kind == K_COORD)
        return 0;
    if (node->kind != K_SHAPE)
        return -1; /* a group, a primitive, an unknown type: Python walks those */
    if (node->f[1].kind != V_NODE)
        return 0; /* no geometry node: nothing drawn */
    if (s->nodes[node->f[1].a].kind != K_IFS)
        return -1;
    *ifs = &s->nodes[node->f[1].a];
    return split_face_set(s, *ifs);
}

static void
free_scan(Scan *s)
{
    PyMem_Free(s->nodes);
    PyMem_Free(s->nums);
    PyMem_Free(s->top);
    PyMem_Free(s->sizes);
    PyMem_Free(s->corners);
    PyMem_Free(s->defs);
}

/* The counts and the mesh of a parsed file, as SceneWalker.count/.walk and MeshBuilder
 * would make them; None when anything is out of the ordinary. */
static PyObject *
build(Scan *s, long long max_triangles, long long max_visits)
{
    int64_t triangles = 0, visits = 0, vertex_count = 0, polygon_count = 0, corner_count = 0;
    PyObject *vertices = NULL, *sizes = NULL, *corners = NULL, *result;
    double *v_out;
    int64_t *s_out, *c_out;
    size_t t;
    Node *ifs;

    /* counting: each top-level Shape is one visit, its geometry node another */
    for (t = 0; t < s->n_top; t++) {
        if (face_set_of(s, &s->nodes[s->top[t]], &ifs) < 0)
            return Py_None;
        visits += (s->nodes[s->top[t]].kind == K_SHAPE && s->nodes[s->top[t]].f[1].kind == V_NODE) ? 2 : 1;
        if (ifs != NULL)
            triangles += ifs->triangles;
        if (triangles > max_triangles || visits > max_visits)
            return Py_None; /* Python refuses it, with its message */
    }
    /* placing: a Coordinate's points go in once, where it is first drawn */
    for (t = 0; t < s->n_top; t++) {
        face_set_of(s, &s->nodes[s->top[t]], &ifs);
        if (ifs == NULL || ifs->triangles == 0)
            continue;
        Node *coord = &s->nodes[ifs->f[1].a];
        if (coord->vertex_offset < 0) {
            int64_t count = coord->f[1].b / 3;
            if (vertex_count + count > max_triangles)
                return Py_None; /* MeshBuilder's vertex limit */
            coord->vertex_offset = vertex_count;
            vertex_count += count;
        }
        polygon_count += ifs->poly_count;
        corner_count += ifs->corner_count;
    }
    vertices = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(vertex_count * 3 * sizeof(double)));
    sizes = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(polygon_count * sizeof(int64_t)));
    corners = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(corner_count * sizeof(int64_t)));
    if (vertices == NULL || sizes == NULL || corners == NULL)
        goto fail;
    v_out = (double *)PyByteArray_AS_STRING(vertices);
    s_out = (int64_t *)PyByteArray_AS_STRING(sizes);
    c_out = (int64_t *)PyByteArray_AS_STRING(corners);
    for (t = 0; t < s->n_top; t++) {
        int64_t k, j, at;
        Node *coord;
        face_set_of(s, &s->nodes[s->top[t]], &ifs);
        if (ifs == NULL || ifs->triangles == 0)
            continue;
        coord = &s->nodes[ifs->f[1].a];
        if (!coord->copied) {
            memcpy(v_out + 3 * coord->vertex_offset, s->nums + coord->f[1].a,
                   (size_t)coord->f[1].b * sizeof(double));
            coord->copied = 1;
        }
        memcpy(s_out, s->sizes + ifs->poly_start, (size_t)ifs->poly_count * sizeof(int64_t));
        s_out += ifs->poly_count;
        at = ifs->corner_start;
        for (k = 0; k < ifs->poly_count; k++) {
            int64_t size = s->sizes[ifs->poly_start + k];
            const int64_t *polygon = s->corners + at;
            if (ifs->f[3].kind == V_BOOL && ifs->f[3].a == 0) {
                /* ccw FALSE: geometry.reverse_winding, a b c d -> a d c b */
                c_out[0] = polygon[0] + coord->vertex_offset;
                for (j = 1; j < size; j++)
                    c_out[j] = polygon[size - j] + coord->vertex_offset;
            }
            else
                for (j = 0; j < size; j++)
                    c_out[j] = polygon[j] + coord->vertex_offset;
            c_out += size;
            at += size;
        }
    }
    result = Py_BuildValue("(NNNLLL)", vertices, sizes, corners, (long long)triangles,
                           (long long)visits, (long long)vertex_count);
    if (result == NULL) {
        PyErr_Clear();
        return Py_None;
    }
    return result;
fail:
    Py_XDECREF(vertices);
    Py_XDECREF(sizes);
    Py_XDECREF(corners);
    PyErr_Clear();
    return Py_None;
}

PyDoc_STRVAR(scan_doc,
"scan(data, max_triangles, max_visits)\n--\n\n"
"The mesh of a flat VRML 2.0 file, or None when the Python reader must read it.\n\n"
"Returns (vertices, face_sizes, face_indices, triangles, visits, vertex_count):\n"
"three bytearrays of float64 (x y z per vertex), int64 and int64, and the counts\n"
"SceneWalker.count gives, for the limits. None for anything unusual, including\n"
"every file that gives an error or a warning.");

static PyObject *
scan(PyObject *self, PyObject *args)
{
    PyObject *data, *result;
    long long max_triangles, max_visits;
    Scan s;
    (void)self;
    if (!PyArg_ParseTuple(args, "SLL:scan", &data, &max_triangles, &max_visits))
        return NULL;
    memset(&s, 0, sizeof(s));
    s.p = (const unsigned char *)PyBytes_AS_STRING(data);
    s.end = s.p + PyBytes_GET_SIZE(data);
    /* exactly "#VRML V2." at the start: parser.read_header gives version 2, no warning */
    if (PyBytes_GET_SIZE(data) < 9 || memcmp(s.p, "#VRML V2.", 9) != 0)
        Py_RETURN_NONE;
    if (read_file(&s) < 0) {
        PyErr_Clear();
        free_scan(&s);
        Py_RETURN_NONE;
    }
    result = build(&s, max_triangles, max_visits);
    free_scan(&s);
    if (result == Py_None)
        Py_INCREF(result);
    return result;
}

static PyObject *
known_other(void)
{
    PyObject *names = PyTuple_New(sizeof(KNOWN_OTHER) / sizeof(*KNOWN_OTHER) - 1);
    Py_ssize_t i;
    if (names == NULL)
        return NULL;
    for (i = 0; KNOWN_OTHER[i] != NULL; i++) {
        PyObject *name = PyUnicode_FromString(KNOWN_OTHER[i]);
        if (name == NULL) {
            Py_DECREF(names);
            return NULL;
        }
        PyTuple_SET_ITEM(names, i, name);
    }
    return names;
}

static PyMethodDef methods[] = {
    {"scan", scan, METH_VARARGS, scan_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_scan",
    "Fast path of the VRML reader for flat VRML 2.0 files (see _scan.c).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC
PyInit__scan(void)
{
    PyObject *m = PyModule_Create(&module), *names;
    if (m == NULL)
        return NULL;
    names = known_other();
    if (names == NULL || PyModule_AddObject(m, "KNOWN_OTHER", names) < 0) {
        Py_XDECREF(names);
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
