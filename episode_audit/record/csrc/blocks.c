#include "stepfast.h"

/* ------------------------------------------------------------------ counting a block

   count_rows(block, n) counts a block's n step rows into their episodes as block.count_block's
   Python does (_count_rows, _add_totals): each live segment's rows add to its episode's steps,
   return (the rewards added one by one, in row order, to the running return) and end time;
   rows stepped after an ending add to after_end. It returns (episode column, step column,
   names) as int64 arrays and:
   - None when the block has no reward terms;
   - the names, a tuple, when every row with terms holds the same distinct plain names (exact
     str, UTF-8 encodable) in the same order: their totals are added here, one value at a time
     in row order, as the Python adds them;
   - False when the terms are any other: their totals are left to the Python.
   It checks everything before it changes anything, and returns None (nothing counted: the
   Python path counts the block) for a block it does not take as it is. */

typedef struct {
    Py_ssize_t start, end; /* its rows */
    long long index, first;
    int live;
    PyObject *episode; /* borrowed; NULL for a segment without rows */
} Span;

/* The segment `item` (start, episode index, first step, counted) into `span`: 1, or 0 when it
   is not of that form (no error set), -1 with an error. */
static int read_segment(PyObject *item, Span *span)
{
    if (!PyTuple_CheckExact(item) || PyTuple_GET_SIZE(item) != 4)
        return 0;
    PyObject *start = PyTuple_GET_ITEM(item, 0), *index = PyTuple_GET_ITEM(item, 1),
             *first = PyTuple_GET_ITEM(item, 2), *live = PyTuple_GET_ITEM(item, 3);
    if (!PyLong_CheckExact(start) || !PyLong_CheckExact(index) || !PyLong_CheckExact(first) ||
        !PyBool_Check(live))
        return 0;
    int overflow = 0;
    span->start = PyLong_AsSsize_t(start);
    span->index = PyLong_AsLongLongAndOverflow(index, &overflow);
    if (!overflow)
        span->first = PyLong_AsLongLongAndOverflow(first, &overflow);
    if (PyErr_Occurred()) {
        if (!PyErr_ExceptionMatches(PyExc_OverflowError))
            return -1;
        PyErr_Clear();
        return 0;
    }
    span->live = live == Py_True;
    span->episode = NULL;
    return !overflow;
}

/* An episode the counting may write: its slots are of the types it writes. */
static int countable(PyObject *ep)
{
    return Py_IS_TYPE(ep, episode_type) && PyFloat_CheckExact(SLOT(ep, off_ep[E_RET])) &&
           PyLong_CheckExact(SLOT(ep, off_ep[E_STEPS])) &&
           PyLong_CheckExact(SLOT(ep, off_ep[E_AFTER_END])) &&
           PyDict_CheckExact(SLOT(ep, off_ep[E_TOTALS]));
}

/* The block's terms: 1 when uniform (`*k` names, the first row's keys, each row's the same),
   0 when not (no error set), -1 with an error. */
static int uniform_terms(PyObject *block, Py_ssize_t n, Py_ssize_t *k)
{
    PyObject *rows = SLOT(block, off_term_rows), *counts = SLOT(block, off_term_counts),
             *keys = SLOT(block, off_term_keys), *vals = SLOT(block, off_term_vals);
    if (!Py_IS_TYPE(rows, array_type) || !Py_IS_TYPE(counts, array_type) ||
        !Py_IS_TYPE(vals, array_type) || !PyList_CheckExact(keys))
        return 0;
    Py_ssize_t r = Py_SIZE(rows);
    if (Py_SIZE(counts) != r)
        return 0;
    const long long *row = (const long long *)((ArrayObject *)rows)->ob_item;
    const long long *count = (const long long *)((ArrayObject *)counts)->ob_item;
    long long each = count[0];
    if (each < 1 || each > MAX_TERMS || PyList_GET_SIZE(keys) != r * each ||
        Py_SIZE(vals) != r * each)
        return 0;
    for (Py_ssize_t i = 0; i < r; i++)
        if (count[i] != each || row[i] < (i ? row[i - 1] + 1 : 0) || row[i] >= n)
            return 0;
    PyObject **key = ((PyListObject *)keys)->ob_item;
    for (long long j = 0; j < each; j++) {
        if (!PyUnicode_CheckExact(key[j]))
            return 0;
        if (PyUnicode_AsUTF8AndSize(key[j], NULL) == NULL) { /* (a lone surrogate) */
            if (!PyErr_ExceptionMatches(PyExc_UnicodeEncodeError))
                return -1;
            PyErr_Clear();
            return 0;
        }
        for (long long i = 0; i < j; i++)
            if (PyUnicode_Compare(key[i], key[j]) == 0)
                return 0;
    }
    for (Py_ssize_t i = each; i < r * each; i++) {
        PyObject *a = key[i], *b = key[i % each];
        if (a != b && (!PyUnicode_CheckExact(a) || PyUnicode_Compare(a, b) != 0))
            return 0;
    }
    *k = (Py_ssize_t)each;
    return 1;
}

/* The live episode's totals hold a float, or nothing, under each name: 1, or 0. */
static int totals_ok(PyObject *ep, PyObject *names)
{
    PyObject *totals = SLOT(ep, off_ep[E_TOTALS]);
    for (Py_ssize_t j = 0; j < PyTuple_GET_SIZE(names); j++) {
        PyObject *total = PyDict_GetItemWithError(totals, PyTuple_GET_ITEM(names, j));
        if (total == NULL ? PyErr_Occurred() != NULL : !PyFloat_CheckExact(total))
            return 0;
    }
    return 1;
}

/* Set slot `off` of `obj` to `value` (a new reference, may be NULL: -1). */
static int set_slot(PyObject *obj, Py_ssize_t off, PyObject *value)
{
    if (value == NULL)
        return -1;
    Py_SETREF(SLOT(obj, off), value);
    return 0;
}

static int add_to_int(PyObject *ep, Py_ssize_t off, Py_ssize_t add)
{
    PyObject *more = PyLong_FromSsize_t(add);
    if (more == NULL)
        return -1;
    PyObject *sum = PyNumber_Add(SLOT(ep, off), more);
    Py_DECREF(more);
    return set_slot(ep, off, sum);
}

/* Add the span's term values to its episode's totals, one at a time in row order. */
static int add_totals(PyObject *block, const Span *s, PyObject *names, Py_ssize_t *at)
{
    PyObject *rows = SLOT(block, off_term_rows), *totals = SLOT(s->episode, off_ep[E_TOTALS]);
    const long long *row = (const long long *)((ArrayObject *)rows)->ob_item;
    const double *val = (const double *)((ArrayObject *)SLOT(block, off_term_vals))->ob_item;
    Py_ssize_t k = PyTuple_GET_SIZE(names), r = Py_SIZE(rows), p = *at;
    while (p < r && row[p] < s->start)
        p++;
    if (p == r || row[p] >= s->end) {
        *at = p;
        return 0;
    }
    double acc[MAX_TERMS];
    for (Py_ssize_t j = 0; j < k; j++) {
        PyObject *total = PyDict_GetItemWithError(totals, PyTuple_GET_ITEM(names, j));
        acc[j] = total == NULL ? 0.0 : PyFloat_AS_DOUBLE(total);
    }
    for (; p < r && row[p] < s->end; p++)
        for (Py_ssize_t j = 0; j < k; j++)
            acc[j] += val[p * k + j];
    *at = p;
    for (Py_ssize_t j = 0; j < k; j++) {
        PyObject *total = PyFloat_FromDouble(acc[j]);
        if (total == NULL || PyDict_SetItem(totals, PyTuple_GET_ITEM(names, j), total) < 0) {
            Py_XDECREF(total);
            return -1;
        }
        Py_DECREF(total);
    }
    return 0;
}

/* Count the spans into their episodes (checked), and fill the index columns. */
static int count_spans(PyObject *block, const Span *spans, Py_ssize_t m, Py_ssize_t n,
                       long long *episode, long long *step, PyObject *names)
{
    const double *reward = (const double *)((ArrayObject *)SLOT(block, off_rewards))->ob_item;
    const long long *time = (const long long *)((ArrayObject *)SLOT(block, off_times))->ob_item;
    Py_ssize_t before = m ? spans[0].start : n, at = 0;
    for (Py_ssize_t row = 0; row < before; row++) { /* rows before any reset: no episode */
        episode[row] = -1;
        step[row] = row;
    }
    for (Py_ssize_t i = 0; i < m; i++) {
        const Span *s = &spans[i];
        for (Py_ssize_t row = s->start; row < s->end; row++) {
            episode[row] = s->index;
            step[row] = s->first + (row - s->start);
        }
        if (s->episode == NULL)
            continue;
        PyObject *ep = s->episode;
        if (!s->live) {
            if (add_to_int(ep, off_ep[E_AFTER_END], s->end - s->start) < 0)
                return -1;
            continue;
        }
        double ret = PyFloat_AS_DOUBLE(SLOT(ep, off_ep[E_RET]));
        for (Py_ssize_t row = s->start; row < s->end; row++)
            ret += reward[row];
        if (set_slot(ep, off_ep[E_RET], PyFloat_FromDouble(ret)) < 0 ||
            add_to_int(ep, off_ep[E_STEPS], s->end - s->start) < 0 ||
            set_slot(ep, off_ep[E_END_NS], PyLong_FromLongLong(time[s->end - 1])) < 0)
            return -1;
        if (names != NULL && add_totals(block, s, names, &at) < 0)
            return -1;
    }
    return 0;
}

/* Read and check the block's segments into `spans` (m of them): 1, 0 (declined), -1. */
static int read_spans(PyObject *block, Py_ssize_t n, Span *spans, Py_ssize_t m)
{
    PyObject *segments = SLOT(block, off_segments), *episodes = SLOT(block, off_episodes);
    for (Py_ssize_t i = 0; i < m; i++) {
        int ok = read_segment(PyList_GET_ITEM(segments, i), &spans[i]);
        if (ok <= 0)
            return ok;
        if (spans[i].start < (i ? spans[i - 1].start : 0) || spans[i].start > n)
            return 0;
        if (i)
            spans[i - 1].end = spans[i].start;
    }
    if (m)
        spans[m - 1].end = n;
    for (Py_ssize_t i = 0; i < m; i++) {
        if (spans[i].end == spans[i].start)
            continue;
        PyObject *index = PyTuple_GET_ITEM(PyList_GET_ITEM(segments, i), 1);
        PyObject *ep = PyDict_GetItemWithError(episodes, index);
        if (ep == NULL)
            return PyErr_Occurred() ? -1 : 0;
        if (!countable(ep))
            return 0;
        spans[i].episode = ep;
    }
    return 1;
}

PyObject *count_rows(PyObject *module, PyObject *args)
{
    PyObject *block;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "On:count_rows", &block, &n))
        return NULL;
    if (!configured || !Py_IS_TYPE(block, block_type) || n < 1)
        Py_RETURN_NONE;
    PyObject *segments = SLOT(block, off_segments), *episodes = SLOT(block, off_episodes),
             *rewards = SLOT(block, off_rewards), *times = SLOT(block, off_times),
             *term_rows = SLOT(block, off_term_rows), *term_keys = SLOT(block, off_term_keys);
    if (!PyList_CheckExact(segments) || !PyDict_CheckExact(episodes) ||
        !Py_IS_TYPE(rewards, array_type) || !Py_IS_TYPE(times, array_type) ||
        Py_SIZE(rewards) < n || Py_SIZE(times) != n || !Py_IS_TYPE(term_rows, array_type))
        Py_RETURN_NONE;
    Py_ssize_t m = PyList_GET_SIZE(segments), k = 0;
    PyObject *names = NULL, *result = NULL, *episode = NULL, *step = NULL;
    Span *spans = PyMem_Malloc((m ? m : 1) * sizeof(Span));
    if (spans == NULL)
        return PyErr_NoMemory();
    int ok = read_spans(block, n, spans, m);
    if (ok > 0 && Py_SIZE(term_rows)) {
        int uniform = uniform_terms(block, n, &k);
        if (uniform < 0)
            goto done;
        if (uniform) {
            names = PyList_GetSlice(term_keys, 0, k);
            Py_XSETREF(names, names == NULL ? NULL : PyList_AsTuple(names));
            if (names == NULL)
                goto done;
            for (Py_ssize_t i = 0; i < m && ok > 0; i++)
                if (spans[i].episode != NULL && spans[i].live)
                    ok = totals_ok(spans[i].episode, names);
        }
    }
    if (ok <= 0) {
        if (ok == 0 && !PyErr_Occurred())
            result = Py_NewRef(Py_None);
        goto done;
    }
    npy_intp dims[1] = {n};
    episode = PyArray_SimpleNew(1, dims, NPY_INT64);
    step = episode == NULL ? NULL : PyArray_SimpleNew(1, dims, NPY_INT64);
    if (step == NULL ||
        count_spans(block, spans, m, n, PyArray_DATA((PyArrayObject *)episode),
                    PyArray_DATA((PyArrayObject *)step), names) < 0)
        goto done;
    PyObject *third = names != NULL ? names : Py_SIZE(term_rows) ? Py_False : Py_None;
    result = PyTuple_Pack(3, episode, step, third);
done:
    PyMem_Free(spans);
    Py_XDECREF(names);
    Py_XDECREF(episode);
    Py_XDECREF(step);
    return result;
}

/* repeated_text(names, times): the buffers of block.repeated_text's string array, the names
   (a tuple of exact str, UTF-8 encodable) repeated `times` times: (value offsets, int32, and
   the UTF-8 data), as bytes; None for other names, or past 2 GiB of text. */
PyObject *repeated_text(PyObject *module, PyObject *args)
{
    PyObject *names;
    Py_ssize_t times;
    if (!PyArg_ParseTuple(args, "O!n:repeated_text", &PyTuple_Type, &names, &times))
        return NULL;
    Py_ssize_t k = PyTuple_GET_SIZE(names), size = 0;
    if (times < 1 || k < 1 || k > MAX_TERMS)
        Py_RETURN_NONE;
    const char *text[MAX_TERMS];
    Py_ssize_t len[MAX_TERMS];
    for (Py_ssize_t j = 0; j < k; j++) {
        PyObject *name = PyTuple_GET_ITEM(names, j);
        text[j] = PyUnicode_CheckExact(name) ? PyUnicode_AsUTF8AndSize(name, &len[j]) : NULL;
        if (text[j] == NULL) {
            if (PyErr_Occurred() && !PyErr_ExceptionMatches(PyExc_UnicodeEncodeError))
                return NULL;
            PyErr_Clear();
            Py_RETURN_NONE;
        }
        size += len[j];
    }
    if (times > (INT32_MAX - 1) / k || (size && times > INT32_MAX / size))
        Py_RETURN_NONE;
    PyObject *offsets = PyBytes_FromStringAndSize(NULL, (k * times + 1) * 4);
    PyObject *data = offsets == NULL ? NULL : PyBytes_FromStringAndSize(NULL, size * times);
    if (data == NULL) {
        Py_XDECREF(offsets);
        return NULL;
    }
    int32_t *off = (int32_t *)PyBytes_AS_STRING(offsets), at = 0;
    char *out = PyBytes_AS_STRING(data);
    off[0] = 0;
    for (Py_ssize_t i = 0; i < times; i++)
        for (Py_ssize_t j = 0; j < k; j++) {
            memcpy(out + at, text[j], len[j]);
            at += (int32_t)len[j];
            off[i * k + j + 1] = at;
        }
    PyObject *result = PyTuple_Pack(2, offsets, data);
    Py_DECREF(offsets);
    Py_DECREF(data);
    return result;
}

/* sparse_text(n, values): the buffers of text_array([values.get(row) for row in range(n)]),
   `values` a dict of rows (ascending, 0 to n - 1) to exact str (UTF-8 encodable) or None:
   (validity bitmap, int32 value offsets, UTF-8 data, null count), as bytes; None for any
   other dict (or past 2 GiB of text). */
PyObject *sparse_text(PyObject *module, PyObject *args)
{
    PyObject *values, *validity = NULL, *offsets = NULL, *data = NULL, *result = NULL;
    Py_ssize_t n, pos = 0, size = 0, last = -1, nulls;
    PyObject *row, *value;
    if (!PyArg_ParseTuple(args, "nO!:sparse_text", &n, &PyDict_Type, &values))
        return NULL;
    if (n < 1 || n > INT32_MAX)
        Py_RETURN_NONE;
    while (PyDict_Next(values, &pos, &row, &value)) {
        Py_ssize_t r = PyLong_CheckExact(row) ? PyLong_AsSsize_t(row) : -1, len = 0;
        if (r == -1 && PyErr_Occurred()) {
            if (!PyErr_ExceptionMatches(PyExc_OverflowError))
                return NULL;
            PyErr_Clear();
        }
        if (r <= last || r >= n)
            Py_RETURN_NONE;
        last = r;
        if (value == Py_None)
            continue;
        if (!PyUnicode_CheckExact(value) || PyUnicode_AsUTF8AndSize(value, &len) == NULL) {
            if (PyErr_Occurred() && !PyErr_ExceptionMatches(PyExc_UnicodeEncodeError))
                return NULL;
            PyErr_Clear();
            Py_RETURN_NONE;
        }
        if (len > INT32_MAX - size)
            Py_RETURN_NONE;
        size += len;
    }
    validity = PyBytes_FromStringAndSize(NULL, (n + 7) / 8);
    offsets = validity == NULL ? NULL : PyBytes_FromStringAndSize(NULL, (n + 1) * 4);
    data = offsets == NULL ? NULL : PyBytes_FromStringAndSize(NULL, size);
    if (data == NULL)
        goto done;
    unsigned char *bits = (unsigned char *)PyBytes_AS_STRING(validity);
    int32_t *off = (int32_t *)PyBytes_AS_STRING(offsets), at = 0;
    char *out = PyBytes_AS_STRING(data);
    memset(bits, 0, (n + 7) / 8);
    Py_ssize_t next = 0;
    nulls = n;
    pos = 0;
    while (PyDict_Next(values, &pos, &row, &value)) {
        Py_ssize_t r = PyLong_AsSsize_t(row), len;
        for (; next <= r; next++)
            off[next] = at;
        if (value == Py_None)
            continue;
        const char *text = PyUnicode_AsUTF8AndSize(value, &len);
        memcpy(out + at, text, len);
        at += (int32_t)len;
        bits[r / 8] |= (unsigned char)(1u << (r % 8));
        nulls--;
    }
    for (; next <= n; next++)
        off[next] = at;
    result = Py_BuildValue("(OOOn)", validity, offsets, data, nulls);
done:
    Py_XDECREF(validity);
    Py_XDECREF(offsets);
    Py_XDECREF(data);
    return result;
}
