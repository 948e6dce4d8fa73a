#include "stepfast.h"

/* ------------------------------------------------------------------ episode records

   episode_json(ended, offset, games, quote, to_json) writes the JSON records of the ended
   episodes (the file's pending list of (Episode, ending dict)) as episode_records._episode_json
   does, and their end times. Only the common record is written here, the one
   episode_records._plain_episode_json writes: no error, no options, a finite float return, int fields, str texts. If any episode
   is another, it returns None and the Python path writes them all. Texts that are not plain
   printable ASCII are quoted by `quote` (json's encode_basestring_ascii), term totals other
   than texts to finite floats by `to_json`: the same bytes, made where they are made in Python. */

typedef struct {
    char *data;
    Py_ssize_t len, cap;
} Text;

/* Append `n` bytes: 1, or 0 with MemoryError. */
static int text_put(Text *t, const char *s, Py_ssize_t n)
{
    if (t->len + n > t->cap) {
        Py_ssize_t cap = 2 * (t->len + n) + 256;
        char *data = PyMem_Realloc(t->data, cap);
        if (data == NULL) {
            PyErr_NoMemory();
            return 0;
        }
        t->data = data;
        t->cap = cap;
    }
    memcpy(t->data + t->len, s, n);
    t->len += n;
    return 1;
}

static int text_cstr(Text *t, const char *s) { return text_put(t, s, (Py_ssize_t)strlen(s)); }

/* Append `v` in decimal, as Python's int formats it (snprintf's locale handling is slower). */
static int text_ll(Text *t, long long v)
{
    char digits[24], *p = digits + sizeof(digits);
    unsigned long long u = v < 0 ? 0ull - (unsigned long long)v : (unsigned long long)v;
    do {
        *--p = (char)('0' + u % 10);
        u /= 10;
    } while (u);
    if (v < 0)
        *--p = '-';
    return text_put(t, p, digits + sizeof(digits) - p);
}

/* `value` + `add` into `*out` when `value` is an int and the sum fits in 64 bits: 1; 0 when
   not (not plain: no error set); -1 with an error. */
static int int_plus(PyObject *value, long long add, long long *out)
{
    if (!PyLong_CheckExact(value))
        return 0;
    int overflow = 0;
    long long v = PyLong_AsLongLongAndOverflow(value, &overflow);
    if (overflow || (add > 0 && v > LLONG_MAX - add) || (add < 0 && v < LLONG_MIN - add))
        return 0;
    if (v == -1 && PyErr_Occurred())
        return -1;
    *out = v + add;
    return 1;
}

/* Append `value` + `add` in decimal (see int_plus): 1; 0 when not plain; -1 with an error. */
static int text_int(Text *t, PyObject *value, long long add)
{
    long long v;
    int got = int_plus(value, add, &v);
    return got <= 0 ? got : (text_ll(t, v) ? 1 : -1);
}

/* Append `value` as json.dumps quotes a str (ASCII, escaped): 1; 0 when it is no str; -1 with
   an error. Printable ASCII without '"' or '\\' is copied; any other text goes to `quote`. */
static int text_str(Text *t, PyObject *value, PyObject *quote)
{
    if (!PyUnicode_CheckExact(value))
        return 0;
    if (PyUnicode_IS_ASCII(value)) {
        const char *s = (const char *)PyUnicode_DATA(value);
        Py_ssize_t n = PyUnicode_GET_LENGTH(value), i = 0;
        while (i < n && s[i] >= 0x20 && s[i] < 0x7f && s[i] != '"' && s[i] != '\\')
            i++;
        if (i == n)
            return text_put(t, "\"", 1) && text_put(t, s, n) && text_put(t, "\"", 1) ? 1 : -1;
    }
    PyObject *quoted = PyObject_CallOneArg(quote, value);
    if (quoted == NULL)
        return -1;
    Py_ssize_t n;
    const char *s = PyUnicode_Check(quoted) ? PyUnicode_AsUTF8AndSize(quoted, &n) : NULL;
    int ok = s != NULL && text_put(t, s, n);
    Py_DECREF(quoted);
    if (s == NULL && !PyErr_Occurred())
        PyErr_SetString(PyExc_TypeError, "quote() gave no str");
    return ok ? 1 : -1;
}

/* The term totals `{"name":total,...}` as to_json writes a dict of texts to finite floats
   (json's encoder: the names quoted, each float's repr): 1; 0 (nothing written) for any other
   dict, which to_json then writes; -1 with an error. */
static int text_totals(Text *t, PyObject *totals, PyObject *quote)
{
    Py_ssize_t pos = 0, start = t->len;
    PyObject *name, *total;
    while (PyDict_Next(totals, &pos, &name, &total))
        if (!PyUnicode_CheckExact(name) || !PyFloat_CheckExact(total) ||
            !isfinite(PyFloat_AS_DOUBLE(total)))
            return 0;
    if (!text_put(t, "{", 1))
        return -1;
    pos = 0;
    while (PyDict_Next(totals, &pos, &name, &total)) {
        if ((t->len > start + 1 && !text_put(t, ",", 1)) || text_str(t, name, quote) <= 0)
            return -1;
        char *repr = PyOS_double_to_string(PyFloat_AS_DOUBLE(total), 'r', 0, Py_DTSF_ADD_DOT_0, NULL);
        if (repr == NULL)
            return -1;
        int ok = text_put(t, ":", 1) && text_cstr(t, repr);
        PyMem_Free(repr);
        if (!ok)
            return -1;
    }
    return text_put(t, "}", 1) ? 1 : -1;
}

/* `,"key":` and then the value as `put` writes it (text_int / text_str results). */
#define PUT_FIELD(key, expr)                                                                       \
    do {                                                                                           \
        if (!text_cstr(t, key))                                                                    \
            return -1;                                                                             \
        int got_ = (expr);                                                                         \
        if (got_ <= 0)                                                                             \
            return got_;                                                                           \
    } while (0)

/* The record of one ended episode, appended to `t`: 1; 0 when it is not a common one; -1 with
   an error. `*end` gets its end time (end_ns + offset). */
/* The ending's fields of a common record (borrowed). */
typedef struct {
    PyObject *outcome, *label, *reason, *term, *trunc;
} Ending;

/* Whether (episode, ending) is a common record: no error, no options, a finite float return,
   bool flags, a dict of term totals, an RNG state that is None or JSON bytes. 1 (with `e`
   filled); 0 when it is not; -1 with an error. */
static int common_record(PyObject *episode, PyObject *ending, Ending *e)
{
    PyObject *error = PyDict_GetItemWithError(ending, s_error);
    if (error != Py_None || PyDict_GetItemWithError(ending, s_error_ns) != NULL ||
        PyErr_Occurred())
        return PyErr_Occurred() ? -1 : 0;
    PyObject *ret = SLOT(episode, off_ep[E_RET]);
    if (SLOT(episode, off_ep[E_OPTIONS]) != Py_None || !PyFloat_CheckExact(ret) ||
        !isfinite(PyFloat_AS_DOUBLE(ret)))
        return 0;
    e->outcome = PyDict_GetItemWithError(ending, s_outcome);
    e->label = PyDict_GetItemWithError(ending, s_failure_label);
    e->reason = PyDict_GetItemWithError(ending, s_truncation_reason);
    e->term = PyDict_GetItemWithError(ending, s_terminated);
    e->trunc = PyDict_GetItemWithError(ending, s_truncated);
    if (e->outcome == NULL || e->label == NULL || e->reason == NULL || e->term == NULL ||
        e->trunc == NULL)
        return PyErr_Occurred() ? -1 : 0;
    PyObject *rng = SLOT(episode, off_ep[E_RNG_JSON]);
    return (e->term == Py_True || e->term == Py_False) &&
           (e->trunc == Py_True || e->trunc == Py_False) &&
           PyDict_CheckExact(SLOT(episode, off_ep[E_TOTALS])) &&
           (rng == Py_None || PyBytes_CheckExact(rng));
}

static int episode_record(Text *t, PyObject *episode, PyObject *ending, long long offset,
                          int games, PyObject *quote, PyObject *to_json, long long *end)
{
    Ending e;
    int got = common_record(episode, ending, &e);
    if (got <= 0)
        return got;
    got = int_plus(SLOT(episode, off_ep[E_END_NS]), offset, end);
    if (got <= 0)
        return got;
    PyObject *outcome = e.outcome, *label = e.label, *reason = e.reason, *term = e.term,
             *trunc = e.trunc;
    PyObject *ret = SLOT(episode, off_ep[E_RET]), *agent = SLOT(episode, off_ep[E_AGENT]);
    PyObject *seed = SLOT(episode, off_ep[E_SEED]), *game = SLOT(episode, off_ep[E_GAME]);
    PyObject *totals = SLOT(episode, off_ep[E_TOTALS]), *rng = SLOT(episode, off_ep[E_RNG_JSON]);
    PUT_FIELD("{\"episode\":", text_int(t, SLOT(episode, off_ep[E_INDEX]), 0));
    PUT_FIELD(",\"env_index\":", text_int(t, SLOT(episode, off_ep[E_ENV_INDEX]), 0));
    if (agent != Py_None)
        PUT_FIELD(",\"agent\":", text_str(t, agent, quote));
    if (seed != Py_None)
        PUT_FIELD(",\"seed\":", text_int(t, seed, 0));
    PUT_FIELD(",\"outcome\":", text_str(t, outcome, quote));
    if (label != Py_None)
        PUT_FIELD(",\"failure_label\":", text_str(t, label, quote));
    if (reason != Py_None)
        PUT_FIELD(",\"truncation_reason\":", text_str(t, reason, quote));
    if (!text_cstr(t, term == Py_True ? ",\"terminated\":true" : ",\"terminated\":false") ||
        !text_cstr(t, trunc == Py_True ? ",\"truncated\":true" : ",\"truncated\":false"))
        return -1;
    PUT_FIELD(",\"length\":", text_int(t, SLOT(episode, off_ep[E_STEPS]), 0));
    char *repr = PyOS_double_to_string(PyFloat_AS_DOUBLE(ret), 'r', 0, Py_DTSF_ADD_DOT_0, NULL);
    if (repr == NULL)
        return -1;
    int ok = text_cstr(t, ",\"return\":") && text_cstr(t, repr) && text_cstr(t, ",\"term_totals\":");
    PyMem_Free(repr);
    if (!ok)
        return -1;
    int plain = text_totals(t, totals, quote);
    if (plain < 0)
        return -1;
    if (!plain) {
        PyObject *json = PyObject_CallOneArg(to_json, totals);
        if (json == NULL)
            return -1;
        ok = PyBytes_Check(json) && text_put(t, PyBytes_AS_STRING(json), PyBytes_GET_SIZE(json));
        Py_DECREF(json);
        if (!ok)
            return PyErr_Occurred() ? -1 : 0;
    }
    PUT_FIELD(",\"start_time_ns\":", text_int(t, SLOT(episode, off_ep[E_START_NS]), offset));
    if (!text_cstr(t, ",\"end_time_ns\":") || !text_ll(t, *end))
        return -1;
    PUT_FIELD(",\"notes\":", text_int(t, SLOT(episode, off_ep[E_NOTES]), 0));
    if (games && game != Py_None)
        PUT_FIELD(",\"game\":", text_int(t, game, 0));
    if (rng != Py_None &&
        !(text_cstr(t, ",\"rng_state\":") && text_put(t, PyBytes_AS_STRING(rng), PyBytes_GET_SIZE(rng))))
        return -1;
    return text_put(t, "}", 1) ? 1 : -1;
}

PyObject *episode_json(PyObject *module, PyObject *args)
{
    PyObject *ended, *quote, *to_json;
    long long offset;
    int games;
    if (!PyArg_ParseTuple(args, "O!LpOO:episode_json", &PyList_Type, &ended, &offset, &games,
                          &quote, &to_json))
        return NULL;
    if (!configured) {
        PyErr_SetString(PyExc_RuntimeError, "_stepfast is not configured");
        return NULL;
    }
    /* a tuple of the items: quote and to_json run Python code, which cannot change it */
    PyObject *items = PyList_AsTuple(ended);
    if (items == NULL)
        return NULL;
    Py_ssize_t n = PyTuple_GET_SIZE(items);
    PyObject *datas = PyList_New(n), *ends = PyList_New(n), *result = NULL;
    Text t = {NULL, 0, 0};
    if (datas == NULL || ends == NULL)
        goto done;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *item = PyTuple_GET_ITEM(items, i);
        if (!PyTuple_CheckExact(item) || PyTuple_GET_SIZE(item) != 2 ||
            !Py_IS_TYPE(PyTuple_GET_ITEM(item, 0), episode_type) ||
            !PyDict_CheckExact(PyTuple_GET_ITEM(item, 1))) {
            result = Py_NewRef(Py_None);
            goto done;
        }
        long long end = 0;
        t.len = 0;
        int got = episode_record(&t, PyTuple_GET_ITEM(item, 0), PyTuple_GET_ITEM(item, 1),
                                 offset, games, quote, to_json, &end);
        if (got < 0)
            goto done;
        if (got == 0) {
            result = Py_NewRef(Py_None);
            goto done;
        }
        PyObject *data = PyBytes_FromStringAndSize(t.data, t.len);
        PyObject *time = PyLong_FromLongLong(end);
        if (data == NULL || time == NULL) {
            Py_XDECREF(data);
            Py_XDECREF(time);
            goto done;
        }
        PyList_SET_ITEM(datas, i, data);
        PyList_SET_ITEM(ends, i, time);
    }
    result = PyTuple_Pack(2, datas, ends);
done:
    PyMem_Free(t.data);
    Py_DECREF(items);
    Py_XDECREF(datas);
    Py_XDECREF(ends);
    return result;
}


/* episode_columns(ended, offset, games): the episode block's columns of the `ended` (episode,
   ending) pairs when every one is a common record (episode_json wrote them all): a dict of
   numpy arrays (int64: episode, env_index, seed, length, start_time_ns, end_time_ns, notes,
   game; bool: terminated, truncated; float64: return), "seed_mask" / "game_mask" (bool arrays
   true where the value is None, or None when none is), and lists of the objects of agent,
   rng_state, outcome, failure_label, truncation_reason and term_totals; times plus `offset`.
   None when one is not a common record, or a value is not of its usual type: the Python path
   (episode_records._episode_batch) builds the block. */

enum { C_EPISODE, C_ENV_INDEX, C_SEED, C_LENGTH, C_START, C_END, C_NOTES, C_GAME, C_INTS };

/* An int64 column value: 1 (set), 0 (not an int that fits: decline), -1 (error). */
static int put_int(PyObject *value, long long add, npy_int64 *out)
{
    long long v;
    int got = int_plus(value, add, &v);
    if (got == 1)
        *out = v;
    return got;
}

static PyObject *new_column(Py_ssize_t n, int type)
{
    npy_intp dims[1] = {n};
    return PyArray_ZEROS(1, dims, type, 0);
}

PyObject *episode_columns(PyObject *module, PyObject *args)
{
    PyObject *ended;
    long long offset;
    int games;
    if (!PyArg_ParseTuple(args, "O!Lp:episode_columns", &PyList_Type, &ended, &offset, &games))
        return NULL;
    if (!configured) {
        PyErr_SetString(PyExc_RuntimeError, "_stepfast is not configured");
        return NULL;
    }
    static const char *int_names[C_INTS] = {"episode", "env_index", "seed", "length",
                                            "start_time_ns", "end_time_ns", "notes", "game"};
    static const char *list_names[6] = {"agent", "rng_state", "outcome", "failure_label",
                                        "truncation_reason", "term_totals"};
    Py_ssize_t n = PyList_GET_SIZE(ended);
    PyObject *ints[C_INTS] = {0}, *lists[6] = {0}, *flags[2] = {0}, *ret_col = NULL,
             *masks[2] = {0}, *result = NULL;
    int ok = 1, any_null[2] = {0, 0};
    for (int c = 0; c < C_INTS; c++)
        ok = ok && (ints[c] = new_column(n, NPY_INT64)) != NULL;
    for (int c = 0; c < 6; c++)
        ok = ok && (lists[c] = PyList_New(n)) != NULL;
    for (int c = 0; c < 2; c++)
        ok = ok && (flags[c] = new_column(n, NPY_BOOL)) != NULL &&
             (masks[c] = new_column(n, NPY_BOOL)) != NULL;
    ok = ok && (ret_col = new_column(n, NPY_DOUBLE)) != NULL;
    if (!ok)
        goto done;
    npy_int64 *col[C_INTS];
    for (int c = 0; c < C_INTS; c++)
        col[c] = (npy_int64 *)PyArray_DATA((PyArrayObject *)ints[c]);
    npy_bool *term_col = PyArray_DATA((PyArrayObject *)flags[0]),
             *trunc_col = PyArray_DATA((PyArrayObject *)flags[1]),
             *seed_null = PyArray_DATA((PyArrayObject *)masks[0]),
             *game_null = PyArray_DATA((PyArrayObject *)masks[1]);
    double *returns = PyArray_DATA((PyArrayObject *)ret_col);
    int declined = 0;
    for (Py_ssize_t i = 0; i < n && !declined; i++) {
        PyObject *item = PyList_GET_ITEM(ended, i);
        if (!PyTuple_CheckExact(item) || PyTuple_GET_SIZE(item) != 2 ||
            !Py_IS_TYPE(PyTuple_GET_ITEM(item, 0), episode_type) ||
            !PyDict_CheckExact(PyTuple_GET_ITEM(item, 1))) {
            declined = 1;
            break;
        }
        PyObject *ep = PyTuple_GET_ITEM(item, 0), *ending = PyTuple_GET_ITEM(item, 1);
        Ending e;
        int common = common_record(ep, ending, &e);
        if (common < 0)
            goto done;
        PyObject *got[6] = {SLOT(ep, off_ep[E_AGENT]), SLOT(ep, off_ep[E_RNG_JSON]), e.outcome,
                            e.label, e.reason, SLOT(ep, off_ep[E_TOTALS])};
        PyObject *seed = SLOT(ep, off_ep[E_SEED]), *game = SLOT(ep, off_ep[E_GAME]);
        if (!common || (got[0] != Py_None && !PyUnicode_CheckExact(got[0])) ||
            !PyUnicode_CheckExact(got[2]) || (got[3] != Py_None && !PyUnicode_CheckExact(got[3])) ||
            (got[4] != Py_None && !PyUnicode_CheckExact(got[4]))) {
            declined = 1;
            break;
        }
        int fits = 1, g;
#define INT_AT(c, value, add)                                                                      \
    if (fits == 1) {                                                                               \
        g = put_int((value), (add), &col[c][i]);                                                   \
        if (g < 0)                                                                                 \
            goto done;                                                                             \
        fits = g;                                                                                  \
    }
        INT_AT(C_EPISODE, SLOT(ep, off_ep[E_INDEX]), 0);
        INT_AT(C_ENV_INDEX, SLOT(ep, off_ep[E_ENV_INDEX]), 0);
        if (seed == Py_None) {
            seed_null[i] = 1;
            any_null[0] = 1;
        } else
            INT_AT(C_SEED, seed, 0);
        INT_AT(C_LENGTH, SLOT(ep, off_ep[E_STEPS]), 0);
        INT_AT(C_START, SLOT(ep, off_ep[E_START_NS]), offset);
        INT_AT(C_END, SLOT(ep, off_ep[E_END_NS]), offset);
        INT_AT(C_NOTES, SLOT(ep, off_ep[E_NOTES]), 0);
        if (!games || game == Py_None) {
            game_null[i] = 1;
            any_null[1] = 1;
        } else
            INT_AT(C_GAME, game, 0);
#undef INT_AT
        if (fits != 1) {
            declined = 1;
            break;
        }
        term_col[i] = e.term == Py_True;
        trunc_col[i] = e.trunc == Py_True;
        returns[i] = PyFloat_AS_DOUBLE(SLOT(ep, off_ep[E_RET]));
        for (int c = 0; c < 6; c++)
            PyList_SET_ITEM(lists[c], i, Py_NewRef(got[c]));
    }
    if (declined) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    result = PyDict_New();
    if (result == NULL)
        goto done;
    ok = PyDict_SetItemString(result, "terminated", flags[0]) == 0 &&
         PyDict_SetItemString(result, "truncated", flags[1]) == 0 &&
         PyDict_SetItemString(result, "return", ret_col) == 0 &&
         PyDict_SetItemString(result, "seed_mask", any_null[0] ? masks[0] : Py_None) == 0 &&
         PyDict_SetItemString(result, "game_mask", any_null[1] ? masks[1] : Py_None) == 0;
    for (int c = 0; ok && c < C_INTS; c++)
        ok = PyDict_SetItemString(result, int_names[c], ints[c]) == 0;
    for (int c = 0; ok && c < 6; c++)
        ok = PyDict_SetItemString(result, list_names[c], lists[c]) == 0;
    if (!ok)
        Py_CLEAR(result);
done:
    for (int c = 0; c < C_INTS; c++)
        Py_XDECREF(ints[c]);
    for (int c = 0; c < 6; c++) /* (a list left part-filled: its unset items are NULL) */
        Py_XDECREF(lists[c]);
    for (int c = 0; c < 2; c++) {
        Py_XDECREF(flags[c]);
        Py_XDECREF(masks[c]);
    }
    Py_XDECREF(ret_col);
    return result;
}

/* A JSON value of str, int, bool, None and dicts of them with str keys (an RNG state), as
   to_json writes it: 1; 0 for any other value (no error set); -1 with an error. */
static int json_value(Text *t, PyObject *value, PyObject *quote, int depth)
{
    if (value == Py_None)
        return text_put(t, "null", 4) ? 1 : -1;
    if (value == Py_True || value == Py_False)
        return text_cstr(t, value == Py_True ? "true" : "false") ? 1 : -1;
    if (PyUnicode_CheckExact(value))
        return text_str(t, value, quote);
    if (PyLong_CheckExact(value)) {
        int overflow = 0;
        long long v = PyLong_AsLongLongAndOverflow(value, &overflow);
        if (!overflow)
            return v == -1 && PyErr_Occurred() ? -1 : (text_ll(t, v) ? 1 : -1);
        PyObject *digits = PyLong_Type.tp_repr(value); /* (json's own choice for an int) */
        if (digits == NULL)
            return -1;
        Py_ssize_t n;
        const char *s = PyUnicode_AsUTF8AndSize(digits, &n);
        int ok = s != NULL && text_put(t, s, n);
        Py_DECREF(digits);
        return ok ? 1 : -1;
    }
    if (!PyDict_CheckExact(value) || depth > 8)
        return 0;
    if (!text_put(t, "{", 1))
        return -1;
    PyObject *key, *item;
    Py_ssize_t pos = 0;
    int first = 1;
    while (PyDict_Next(value, &pos, &key, &item)) {
        if (!PyUnicode_CheckExact(key))
            return 0;
        if (!first && !text_put(t, ",", 1))
            return -1;
        first = 0;
        int got = text_str(t, key, quote);
        if (got <= 0)
            return got;
        if (!text_put(t, ":", 1))
            return -1;
        if ((got = json_value(t, item, quote, depth + 1)) <= 0)
            return got;
    }
    return text_put(t, "}", 1) ? 1 : -1;
}

/* rng_json(state, quote): to_json(state) for a dict of str, int, bool, None and such dicts
   (an RNG state: PCG64's and the other bit generators'), else None. */
PyObject *rng_json(PyObject *module, PyObject *args)
{
    PyObject *state, *quote;
    if (!PyArg_ParseTuple(args, "OO:rng_json", &state, &quote))
        return NULL;
    if (!PyDict_CheckExact(state))
        Py_RETURN_NONE;
    Text t = {NULL, 0, 0};
    int got = json_value(&t, state, quote, 0);
    PyObject *result = got < 0   ? NULL
                       : got == 0 ? Py_NewRef(Py_None)
                                  : PyBytes_FromStringAndSize(t.data, t.len);
    PyMem_Free(t.data);
    return result;
}

/* frame_messages(datas, times, channel, sequence, offset): the MCAP Message records of the
   messages `datas` (bytes) on `channel` at log (and publish) times `times`, numbered from
   `sequence`, as one bytes object; and their message index entries, (time, offset) with the
   first record at `offset`. The same bytes as mcap's Writer.add_message one by one. */
PyObject *frame_messages(PyObject *module, PyObject *args)
{
    PyObject *datas, *times;
    unsigned int channel;
    unsigned long long sequence;
    long long offset;
    if (!PyArg_ParseTuple(args, "O!O!IKL:frame_messages", &PyList_Type, &datas, &PyList_Type,
                          &times, &channel, &sequence, &offset))
        return NULL;
    Py_ssize_t n = PyList_GET_SIZE(datas), size = 0;
    if (PyList_GET_SIZE(times) != n || channel > 0xFFFF) {
        PyErr_SetString(PyExc_ValueError, "frame_messages: one time per message, a u16 channel");
        return NULL;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *data = PyList_GET_ITEM(datas, i);
        if (!PyBytes_CheckExact(data)) {
            PyErr_SetString(PyExc_TypeError, "frame_messages: the messages must be bytes");
            return NULL;
        }
        size += 31 + PyBytes_GET_SIZE(data);
    }
    PyObject *framed = PyBytes_FromStringAndSize(NULL, size), *entries = PyList_New(n);
    if (framed == NULL || entries == NULL)
        goto fail;
    unsigned char *out = (unsigned char *)PyBytes_AS_STRING(framed);
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *data = PyList_GET_ITEM(datas, i), *time = PyList_GET_ITEM(times, i);
        unsigned long long t = PyLong_AsUnsignedLongLong(time);
        if (t == (unsigned long long)-1 && PyErr_Occurred())
            goto fail;
        PyObject *entry = Py_BuildValue("(OL)", time, offset);
        if (entry == NULL)
            goto fail;
        PyList_SET_ITEM(entries, i, entry);
        Py_ssize_t len = PyBytes_GET_SIZE(data);
        unsigned long long fields[4] = {22 + (unsigned long long)len, channel,
                                        (sequence + (unsigned long long)i) & 0xFFFFFFFFull, t};
        /* opcode u8, record length u64, channel u16, sequence u32, log time u64, publish u64;
           little-endian, as struct "<BQHIQQ" packs them */
        unsigned char *p = out;
        *p++ = 0x05;
        for (int b = 0; b < 8; b++)
            *p++ = (unsigned char)(fields[0] >> (8 * b));
        for (int b = 0; b < 2; b++)
            *p++ = (unsigned char)(fields[1] >> (8 * b));
        for (int b = 0; b < 4; b++)
            *p++ = (unsigned char)(fields[2] >> (8 * b));
        for (int k = 0; k < 2; k++)
            for (int b = 0; b < 8; b++)
                *p++ = (unsigned char)(fields[3] >> (8 * b));
        memcpy(p, PyBytes_AS_STRING(data), len);
        out = p + len;
        offset += 31 + len;
    }
    PyObject *result = PyTuple_Pack(2, framed, entries);
    Py_DECREF(framed);
    Py_DECREF(entries);
    return result;
fail:
    Py_XDECREF(framed);
    Py_XDECREF(entries);
    return NULL;
}
