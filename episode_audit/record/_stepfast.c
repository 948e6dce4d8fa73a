/* The recorder's per-step path, compiled: episode_audit.record._stepfast.

   StepRecorder(stream) is called as stream.step(action, result) is, and records the common
   step exactly as Stream.step's fast path does: observation and action copied into their
   column blocks (Box / MultiBinary / MultiDiscrete arrays and Discrete integers), the reward,
   the reward terms of a flat dict of numbers and the time appended. It checks everything
   before it changes anything; any step it does not take as it is (an unusual value, a column
   block or array out of room, a new set of info keys, an ended episode...) is handed, untouched,
   to the Python method, so behaviour and the bytes written are those of the Python path.

   It reads the slotted objects it writes to (Block, Episode, the column buffers) at their
   slot offsets, resolved once from the classes' member descriptors and used only on objects
   of exactly those classes. array.array has no C API: its object layout (CPython's
   Modules/arraymodule.c, the same in 3.10-3.14) is declared here and checked when the module
   loads (layout_ok); a layout that does not match leaves the module unusable, and the
   recorder takes the Python path. The arrays written here hold 8-byte items ('d', 'q'). */

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <string.h>
#include <time.h>

#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <numpy/arrayscalars.h>

#define MAX_TERMS 64

typedef struct {
    PyObject_VAR_HEAD
    char *ob_item;
    Py_ssize_t allocated;
    const void *ob_descr;
    PyObject *weakreflist;
    Py_ssize_t ob_exports;
} ArrayObject;

/* Set by configure(): the classes, and their slots' offsets. */
static PyTypeObject *array_type, *block_type, *episode_type, *flat_type, *nd_type, *int_type;
static PyObject *monotonic_ns;
static Py_ssize_t off_ends, off_flags, off_segments, off_episodes, off_pending,
    off_reset_obs, off_resets;
/* Episode's slots, all of them: begin() makes an Episode as its __init__ would (EPISODE_SLOTS
   must name every slot the class has: configure() checks). */
#define EPISODE_SLOTS 16
static const char *episode_slots[EPISODE_SLOTS] = {
    "after_end", "agent", "end_ns", "ended", "env_index", "game", "index", "notes", "options",
    "options_json", "ret", "rng_json", "seed", "start_ns", "steps", "totals"};
enum { E_AFTER_END, E_AGENT, E_END_NS, E_ENDED, E_ENV_INDEX, E_GAME, E_INDEX, E_NOTES, E_OPTIONS,
       E_OPTIONS_JSON, E_RET, E_RNG_JSON, E_SEED, E_START_NS, E_STEPS, E_TOTALS };
static Py_ssize_t off_ep[EPISODE_SLOTS];
static Py_ssize_t off_obs, off_act, off_rewards, off_times, off_term_vals, off_term_rows,
    off_term_counts, off_term_keys;
static Py_ssize_t off_arr_data, off_arr_n, off_arr_dtype, off_int_data, off_int_n;
static int configured;

static PyObject *s_episode, *s_block, *s_terms_keys, *s_terms_names, *s_block_steps, *s_file,
    *s_flush_at, *s_end_by_flags, *s_auto_flush, *s_step, *s_clock, *s_flag_endings,
    *s_ending_keys, *s_limit_hit, *s_pending, *s_counts, *s_episodes, *s_outcome,
    *s_failure_label, *s_truncation_reason, *s_terminated, *s_truncated, *s_error,
    *s_time_limit, *s_elapsed_steps, *s_max_episode_steps, *s_next_episode, *s_env_index,
    *s_agent, *s_slots, *s_file_clock, *s_error_ns;

#define SLOT(obj, off) (*(PyObject **)((char *)(obj) + (off)))

/* Take `op` out of the cyclic garbage collector's lists, as CPython does itself with a tuple
   or dict that holds no tracked object. Only for the objects a recorder makes per episode (its
   Episode, ending pair, row tuples: native.untrack says which), which hold ints, texts, bools,
   None, JSON data of their own and each other: no reference cycle can pass through them, so
   the collector need not scan them. Otherwise each one is scanned at every young collection
   it lives through, and the episodes waiting for a flush are promoted to the oldest
   generation, whose growth sets off full collections of the whole process. */
static void untrack(PyObject *op)
{
    if (PyObject_IS_GC(op))
        PyObject_GC_UnTrack(op);
}

static PyObject *untrack_object(PyObject *module, PyObject *op)
{
    untrack(op);
    Py_RETURN_NONE;
}

/* The offset of `type`'s object slot `name`, or -1 when it has none by that name (an error
   set only when the lookup itself failed otherwise). */
static Py_ssize_t member_offset(PyTypeObject *type, PyObject *name)
{
    PyObject *descr = PyObject_GetAttr((PyObject *)type, name);
    if (descr == NULL) {
        if (PyErr_ExceptionMatches(PyExc_AttributeError))
            PyErr_Clear();
        return -1;
    }
    Py_ssize_t offset = -1;
    if (Py_IS_TYPE(descr, &PyMemberDescr_Type) &&
        ((PyMemberDescrObject *)descr)->d_member->type == T_OBJECT_EX)
        offset = ((PyMemberDescrObject *)descr)->d_member->offset;
    Py_DECREF(descr);
    return offset;
}

/* The offset of `type`'s object slot `name`; -1 with a TypeError when it has none. */
static Py_ssize_t slot_offset(PyTypeObject *type, const char *name)
{
    PyObject *text = PyUnicode_InternFromString(name);
    if (text == NULL)
        return -1;
    Py_ssize_t offset = member_offset(type, text);
    Py_DECREF(text);
    if (offset < 0 && !PyErr_Occurred())
        PyErr_Format(PyExc_TypeError, "%s.%s is not an object slot", type->tp_name, name);
    return offset;
}

/* ------------------------------------------------------------------ array.array, checked */

static int layout_ok(void)
{
    /* array('d', [1.5, 2.5]): two items, room for them, and no export; then one export. */
    PyObject *mod = PyImport_ImportModule("array"), *arr = NULL, *view = NULL;
    int ok = 0;
    if (mod == NULL)
        return -1;
    arr = PyObject_CallMethod(mod, "array", "s[dd]", "d", 1.5, 2.5);
    if (arr == NULL)
        goto done;
    ArrayObject *a = (ArrayObject *)arr;
    if (Py_SIZE(a) != 2 || a->allocated < 2 || a->ob_exports != 0)
        goto done;
    if (((double *)a->ob_item)[0] != 1.5 || ((double *)a->ob_item)[1] != 2.5)
        goto done;
    view = PyMemoryView_FromObject(arr);
    if (view == NULL)
        goto done;
    ok = a->ob_exports == 1 && PyMemoryView_GET_BUFFER(view)->buf == a->ob_item;
done:
    Py_XDECREF(view);
    Py_XDECREF(arr);
    Py_DECREF(mod);
    if (PyErr_Occurred())
        return -1;
    return ok;
}

/* Make room for `count` more items in `a` (an array.array of items of `itemsize` bytes) as its
   own resize does (PyMem_Realloc of ob_item), doubling: 1, or 0 when it cannot (an exported
   buffer, or no memory: the Python path then decides). */
static int array_room(PyObject *a, Py_ssize_t count, Py_ssize_t itemsize)
{
    ArrayObject *arr = (ArrayObject *)a;
    if (!Py_IS_TYPE(a, array_type) || arr->ob_exports != 0)
        return 0;
    Py_ssize_t need = Py_SIZE(arr) + count;
    if (need <= arr->allocated)
        return 1;
    Py_ssize_t size = need < 128 ? 256 : 2 * need;
    if (size > PY_SSIZE_T_MAX / itemsize)
        return 0;
    char *items = PyMem_Realloc(arr->ob_item, size * itemsize);
    if (items == NULL)
        return 0;
    arr->ob_item = items;
    arr->allocated = size;
    return 1;
}

static inline void array_push_d(PyObject *a, double value)
{
    ArrayObject *arr = (ArrayObject *)a;
    ((double *)arr->ob_item)[Py_SIZE(arr)] = value;
    Py_SET_SIZE(arr, Py_SIZE(arr) + 1);
}

static inline void array_push_q(PyObject *a, long long value)
{
    ArrayObject *arr = (ArrayObject *)a;
    ((long long *)arr->ob_item)[Py_SIZE(arr)] = value;
    Py_SET_SIZE(arr, Py_SIZE(arr) + 1);
}

/* ------------------------------------------------------------------ column buffers */

/* A value checked to go into a column buffer as it is: where its bytes go, from where. */
typedef struct {
    PyObject *buffer;
    PyObject *count; /* the row count after the value (a new reference), made before any write */
    Py_ssize_t n;
    char *dest;
    const void *src;
    Py_ssize_t nbytes;
    long long integer;
    int is_int;
} Pending;

/* Whether `value` goes into `buffer` as its Python append would take it without a note, and
   the buffer's block has room: 1 (filled `p`), 0 (the Python path decides). */
static int plan_value(PyObject *buffer, PyObject *value, Pending *p)
{
    PyTypeObject *type = Py_TYPE(buffer);
    p->buffer = buffer;
    if (type == int_type) {
        PyObject *data = SLOT(buffer, off_int_data), *n_obj = SLOT(buffer, off_int_n);
        if (data == NULL || n_obj == NULL || !PyArray_CheckExact(data) || !PyLong_CheckExact(n_obj))
            return 0;
        long long number;
        if (PyArray_IsScalar(value, Int64)) { /* (Discrete.sample()'s): its value, no int made */
            number = PyArrayScalar_VAL(value, Int64);
        } else {
            if (!PyLong_CheckExact(value) && !PyArray_IsScalar(value, Integer))
                return 0;
            PyObject *index = PyNumber_Index(value);
            if (index == NULL) {
                PyErr_Clear();
                return 0;
            }
            int overflow = 0;
            number = PyLong_AsLongLongAndOverflow(index, &overflow);
            Py_DECREF(index);
            if (overflow || (number == -1 && PyErr_Occurred())) {
                PyErr_Clear();
                return 0;
            }
        }
        Py_ssize_t n = PyLong_AsSsize_t(n_obj);
        PyArrayObject *block = (PyArrayObject *)data;
        if (n < 0 || n >= PyArray_DIM(block, 0) || PyArray_TYPE(block) != NPY_INT64 ||
            !PyArray_IS_C_CONTIGUOUS(block))
            return 0;
        p->n = n;
        p->dest = (char *)PyArray_DATA(block) + n * (Py_ssize_t)sizeof(long long);
        p->integer = number;
        p->is_int = 1;
        p->count = PyLong_FromSsize_t(n + 1);
        if (p->count == NULL) {
            PyErr_Clear();
            return 0;
        }
        return 1;
    }
    if (type != flat_type && type != nd_type)
        return 0;
    PyObject *data = SLOT(buffer, off_arr_data), *n_obj = SLOT(buffer, off_arr_n),
             *dtype = SLOT(buffer, off_arr_dtype);
    if (data == NULL || n_obj == NULL || dtype == NULL || !PyArray_CheckExact(data) ||
        !PyLong_CheckExact(n_obj) || !PyArray_CheckExact(value) || !PyArray_DescrCheck(dtype))
        return 0;
    PyArrayObject *block = (PyArrayObject *)data, *arr = (PyArrayObject *)value;
    int ndim = PyArray_NDIM(arr);
    if (ndim != PyArray_NDIM(block) - 1 || !PyArray_IS_C_CONTIGUOUS(arr) ||
        !PyArray_IS_C_CONTIGUOUS(block))
        return 0;
    if (memcmp(PyArray_DIMS(arr), PyArray_DIMS(block) + 1, ndim * sizeof(npy_intp)) != 0)
        return 0;
    PyArray_Descr *want = (PyArray_Descr *)dtype;
    if (PyArray_DESCR(arr) != want && !PyArray_EquivTypes(PyArray_DESCR(arr), want))
        return 0;
    if (!PyArray_EquivTypes(PyArray_DESCR(block), want))
        return 0;
    Py_ssize_t n = PyLong_AsSsize_t(n_obj);
    if (n < 0 || n >= PyArray_DIM(block, 0))
        return 0;
    p->n = n;
    p->nbytes = PyArray_NBYTES(arr);
    p->dest = (char *)PyArray_DATA(block) + n * p->nbytes;
    p->src = PyArray_DATA(arr);
    p->is_int = 0;
    p->count = PyLong_FromSsize_t(n + 1);
    if (p->count == NULL) {
        PyErr_Clear();
        return 0;
    }
    return 1;
}

/* Write a planned value and count its row (cannot fail: the count was made by plan_value). */
static void commit_value(Pending *p)
{
    if (p->is_int)
        memcpy(p->dest, &p->integer, sizeof(long long));
    else
        memcpy(p->dest, p->src, p->nbytes);
    Py_ssize_t off = Py_TYPE(p->buffer) == int_type ? off_int_n : off_arr_n;
    Py_SETREF(SLOT(p->buffer, off), p->count);
    p->count = NULL;
}

/* ------------------------------------------------------------------ the step */

/* The stream attributes the step reads every time. */
enum { S_EPISODE, S_BLOCK, S_TERMS_KEYS, S_TERMS_NAMES, S_BLOCK_STEPS, S_FLUSH_AT, S_COUNT };
static PyObject **stream_names[S_COUNT] = {&s_episode,     &s_block,       &s_terms_keys,
                                           &s_terms_names, &s_block_steps, &s_flush_at};

typedef struct {
    PyObject_HEAD
    PyObject *stream;
    PyObject *fallback; /* stream.step, the Python path */
    PyObject *file;
    PyObject *clock;
    vectorcallfunc vectorcall;
    Py_ssize_t compiled_steps; /* steps recorded here */
    Py_ssize_t python_steps;   /* steps handed to the Python path */
    Py_ssize_t compiled_resets; /* resets recorded here (begin and reset_row) */
    Py_ssize_t stream_off[S_COUNT]; /* the stream's slots read per step (-1: looked up) */
} StepRecorder;

/* A stream attribute read per step (a new reference; NULL with an error): from its slot when
   the stream's class has one (Stream's __slots__), else looked up by name. */
static PyObject *stream_attr(StepRecorder *self, int which)
{
    Py_ssize_t off = self->stream_off[which];
    if (off >= 0) {
        PyObject *value = SLOT(self->stream, off);
        if (value != NULL)
            return Py_NewRef(value);
    }
    return PyObject_GetAttr(self->stream, *stream_names[which]);
}

static PyObject *python_step(StepRecorder *self, PyObject *action, PyObject *result)
{
    PyObject *args[2] = {action, result};
    self->python_steps++;
    return PyObject_Vectorcall(self->fallback, args, 2, NULL);
}

/* An int as a long long: 0, or -1 with an error (too large, or not an int). Not
   PyLong_AsLongLong, which reads an int of more than one digit (a time in ns) through a byte
   array: ~250 instructions, where this digit loop takes ~20. */
static int as_long_long(PyObject *value, long long *out)
{
    int overflow = 0;
    *out = PyLong_AsLongLongAndOverflow(value, &overflow);
    if (overflow) {
        PyErr_SetString(PyExc_OverflowError, "int too large for a 64-bit time");
        return -1;
    }
    return (*out == -1 && PyErr_Occurred()) ? -1 : 0;
}

/* Read `clock` (time.monotonic_ns read here, any other clock called): 0, or -1 on an error. */
static int call_clock(PyObject *clock, long long *now)
{
    if (clock == monotonic_ns) {
        struct timespec ts;
        if (clock_gettime(CLOCK_MONOTONIC, &ts) == 0) {
            *now = (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec;
            return 0;
        }
    }
    PyObject *value = PyObject_CallNoArgs(clock);
    if (value == NULL)
        return -1;
    int failed = as_long_long(value, now);
    Py_DECREF(value);
    return failed;
}

/* Flush the file (auto_flush) when `full`, or when its flush is due at `now` (EvidenceFile.due);
   -1 on an error. */
static int flush_if_due(StepRecorder *self, long long now, int full)
{
    if (!full) {
        PyObject *flush_at = stream_attr(self, S_FLUSH_AT); /* (the file's, kept by it) */
        if (flush_at == NULL)
            return -1;
        long long at;
        int failed = as_long_long(flush_at, &at);
        Py_DECREF(flush_at);
        if (failed)
            return -1;
        if (now < at)
            return 0;
    }
    PyObject *flushed = PyObject_CallMethodNoArgs(self->file, s_auto_flush);
    if (flushed == NULL)
        return -1;
    Py_DECREF(flushed);
    return 0;
}

/* The terms of `info` as the stream's plan reads them: their count in *count, their values
   in values, the names tuple (borrowed) in *names; 1 ok, 0 the Python path decides. */
static int read_terms(StepRecorder *self, PyObject *info, double *values, Py_ssize_t *count,
                      PyObject **names_out)
{
    int ok = 0;
    PyObject *keys = stream_attr(self, S_TERMS_KEYS), *names = NULL;
    if (keys == NULL || !PyTuple_CheckExact(keys) ||
        PyTuple_GET_SIZE(keys) != PyDict_GET_SIZE(info))
        goto done;
    Py_ssize_t pos = 0, i = 0;
    PyObject *key, *value;
    while (PyDict_Next(info, &pos, &key, &value)) {
        PyObject *planned = PyTuple_GET_ITEM(keys, i++);
        if (key != planned) {
            int same = PyObject_RichCompareBool(key, planned, Py_EQ);
            if (same != 1)
                goto done;
        }
    }
    names = stream_attr(self, S_TERMS_NAMES);
    if (names == NULL || !PyTuple_CheckExact(names) || PyTuple_GET_SIZE(names) > MAX_TERMS)
        goto done;
    Py_ssize_t k = PyTuple_GET_SIZE(names);
    for (Py_ssize_t j = 0; j < k; j++) {
        PyObject *term = PyDict_GetItemWithError(info, PyTuple_GET_ITEM(names, j));
        if (term == NULL)
            goto done;
        double number = PyFloat_AsDouble(term);
        if (number == -1.0 && PyErr_Occurred())
            goto done;
        values[j] = number;
    }
    *count = k;
    *names_out = names; /* a new reference, the caller's */
    names = NULL;
    ok = 1;
done:
    PyErr_Clear();
    Py_XDECREF(keys);
    Py_XDECREF(names);
    return ok;
}

/* Whether the episode's time limit is hit, as the stream's _limit_hit says: its TimeLimit's
   counts read here when both are ints, else the method is called. A new reference. */
static PyObject *limit_hit(PyObject *stream, PyObject *block)
{
    PyObject *time_limit = PyObject_GetAttr(stream, s_time_limit), *elapsed = NULL,
             *limit = NULL, *hit = NULL;
    if (time_limit == NULL)
        return NULL;
    if (time_limit != Py_None) {
        elapsed = PyObject_GetAttr(time_limit, s_elapsed_steps);
        limit = elapsed == NULL ? NULL : PyObject_GetAttr(time_limit, s_max_episode_steps);
        if (limit != NULL && PyLong_CheckExact(elapsed) && PyLong_CheckExact(limit))
            hit = PyObject_RichCompare(elapsed, limit, Py_GE);
        PyErr_Clear();
    }
    if (hit == NULL)
        hit = PyObject_CallMethodOneArg(stream, s_limit_hit, block);
    Py_DECREF(time_limit);
    Py_XDECREF(elapsed);
    Py_XDECREF(limit);
    return hit;
}

/* The plain ending of a final step, as EpisodeStream._end_by_flags finds it: when its info holds
   none of the ending rules' keys, the stream's _flag_endings table's entry for its flags and
   whether the time limit was hit (the stream's _limit_hit, in Python). A new reference to an
   (outcome, failure_label, truncation_reason) tuple; NULL with no error set when the case is
   not plain (the Python method decides), NULL with an error set on an error. */
static PyObject *plain_ending(PyObject *stream, PyObject *block, PyObject *terminated,
                              PyObject *truncated, PyObject *info)
{
    PyObject *table = NULL, *keys = NULL, *hit = NULL, *key = NULL, *plain = NULL;
    table = PyObject_GetAttr(stream, s_flag_endings);
    keys = table == NULL ? NULL : PyObject_GetAttr(stream, s_ending_keys);
    if (keys == NULL) {
        PyErr_Clear();
        goto out;
    }
    if (!PyDict_CheckExact(table) || PyDict_GET_SIZE(table) == 0 || !PyFrozenSet_CheckExact(keys))
        goto out;
    Py_ssize_t pos = 0;
    PyObject *name, *value;
    while (PyDict_Next(info, &pos, &name, &value)) {
        int found = PySet_Contains(keys, name);
        if (found != 0) { /* a key the rules read (or one that cannot be looked up) */
            PyErr_Clear();
            goto out;
        }
    }
    hit = limit_hit(stream, block);
    if (hit == NULL || !PyBool_Check(hit))
        goto out; /* (an error stays set) */
    key = PyTuple_Pack(3, terminated, truncated, hit);
    plain = key == NULL ? NULL : PyDict_GetItemWithError(table, key); /* borrowed */
    if (plain != NULL && (!PyTuple_Check(plain) || PyTuple_GET_SIZE(plain) != 3))
        plain = NULL;
    Py_XINCREF(plain);
out:
    Py_XDECREF(table);
    Py_XDECREF(keys);
    Py_XDECREF(hit);
    Py_XDECREF(key);
    return plain;
}

/* Record the ending `plain` (from plain_ending) of `episode` at its step `row_obj`, as
   EpisodeStream._end_as and end_episode do: the block's ends and flags, the episode ended,
   pending in its file, the file's episode count. 1: recorded; 0: the Python method decides
   (nothing was changed); -1: an error. */
static int record_ending(PyObject *stream, PyObject *episode, PyObject *block, PyObject *row_obj,
                         PyObject *terminated, PyObject *truncated, PyObject *plain)
{
    int done = 0;
    PyObject *file = NULL, *pending = NULL, *counts = NULL, *ends_value = NULL,
             *flags_value = NULL, *ending = NULL, *pair = NULL, *count = NULL;
    PyObject *outcome = PyTuple_GET_ITEM(plain, 0), *failure_label = PyTuple_GET_ITEM(plain, 1),
             *truncation_reason = PyTuple_GET_ITEM(plain, 2);
    PyObject *ends = SLOT(block, off_ends), *flags = SLOT(block, off_flags);
    file = PyObject_GetAttr(stream, s_file);
    pending = file == NULL ? NULL : PyObject_GetAttr(file, s_pending);
    counts = pending == NULL ? NULL : PyObject_GetAttr(file, s_counts);
    if (counts == NULL) {
        PyErr_Clear();
        goto out;
    }
    if (ends == NULL || flags == NULL || !PyDict_CheckExact(ends) || !PyDict_CheckExact(flags) ||
        !PyList_CheckExact(pending) || !PyDict_CheckExact(counts))
        goto out;
    PyObject *episodes = PyDict_GetItemWithError(counts, s_episodes); /* borrowed */
    if (episodes == NULL || !PyLong_CheckExact(episodes)) {
        PyErr_Clear();
        goto out;
    }
    /* Everything made before anything changes (only memory can fail after). */
    ends_value = PyTuple_Pack(
        2, outcome, terminated == Py_True ? failure_label : truncation_reason);
    flags_value = PyTuple_Pack(2, terminated, truncated);
    ending = PyDict_New();
    Py_ssize_t so_far = PyLong_AsSsize_t(episodes);
    if (so_far < 0) {
        PyErr_Clear();
        goto out;
    }
    count = PyLong_FromSsize_t(so_far + 1);
    done = -1;
    if (ends_value == NULL || flags_value == NULL || ending == NULL || count == NULL ||
        PyDict_SetItem(ending, s_outcome, outcome) < 0 ||
        PyDict_SetItem(ending, s_failure_label, failure_label) < 0 ||
        PyDict_SetItem(ending, s_truncation_reason, truncation_reason) < 0 ||
        PyDict_SetItem(ending, s_terminated, terminated) < 0 ||
        PyDict_SetItem(ending, s_truncated, truncated) < 0 ||
        PyDict_SetItem(ending, s_error, Py_None) < 0 ||
        (pair = PyTuple_Pack(2, episode, ending)) == NULL ||
        PyDict_SetItem(ends, row_obj, ends_value) < 0 ||
        PyDict_SetItem(flags, row_obj, flags_value) < 0)
        goto out;
    Py_SETREF(SLOT(episode, off_ep[E_ENDED]), Py_NewRef(Py_True));
    untrack(ends_value);
    untrack(flags_value);
    untrack(pair);
    if (PyList_Append(pending, pair) < 0 || PyDict_SetItem(counts, s_episodes, count) < 0)
        goto out;
    done = 1;
out:
    Py_XDECREF(file);
    Py_XDECREF(pending);
    Py_XDECREF(counts);
    Py_XDECREF(ends_value);
    Py_XDECREF(flags_value);
    Py_XDECREF(ending);
    Py_XDECREF(pair);
    Py_XDECREF(count);
    return done;
}

/* End `episode` by the flags of its step `row` (one of them true): its plain ending recorded
   here, any other by the stream's _end_by_flags. 0, or -1 on an error. */
static int end_by_flags(PyObject *stream, PyObject *episode, PyObject *block, Py_ssize_t row,
                        PyObject *terminated, PyObject *truncated, PyObject *info)
{
    PyObject *row_obj = PyLong_FromSsize_t(row);
    if (row_obj == NULL)
        return -1;
    int done = 0;
    PyObject *plain = plain_ending(stream, block, terminated, truncated, info);
    if (plain != NULL) {
        done = record_ending(stream, episode, block, row_obj, terminated, truncated, plain);
        Py_DECREF(plain);
    } else if (PyErr_Occurred()) {
        done = -1;
    }
    if (done == 0) {
        PyObject *args[7] = {stream, episode, block, row_obj, terminated, truncated, info};
        PyObject *end = PyObject_VectorcallMethod(
            s_end_by_flags, args, 7 | PY_VECTORCALL_ARGUMENTS_OFFSET, NULL);
        done = end == NULL ? -1 : 1;
        Py_XDECREF(end);
    }
    Py_DECREF(row_obj);
    return done < 0 ? -1 : 0;
}

/* After the step at `row` (read at `now`): flush when the block is full or the flush is due.
   0, or -1 on an error. */
static int flush_after_step(StepRecorder *self, long long now, Py_ssize_t row)
{
    PyObject *limit = stream_attr(self, S_BLOCK_STEPS);
    if (limit == NULL)
        return -1;
    Py_ssize_t block_steps = PyLong_AsSsize_t(limit);
    Py_DECREF(limit);
    if (block_steps == -1 && PyErr_Occurred())
        return -1;
    return flush_if_due(self, now, row + 1 >= block_steps);
}

static PyObject *step_impl(StepRecorder *self, PyObject *action, PyObject *result)
{
    if (!PyTuple_CheckExact(result) || PyTuple_GET_SIZE(result) != 5)
        return python_step(self, action, result);
    PyObject *obs = PyTuple_GET_ITEM(result, 0), *reward = PyTuple_GET_ITEM(result, 1),
             *terminated = PyTuple_GET_ITEM(result, 2), *truncated = PyTuple_GET_ITEM(result, 3),
             *info = PyTuple_GET_ITEM(result, 4);
    if (!PyBool_Check(terminated) || !PyBool_Check(truncated) || !PyDict_CheckExact(info))
        return python_step(self, action, result);
    PyObject *stream = self->stream, *episode = NULL, *block = NULL, *names = NULL;
    PyObject *ret = NULL;
    double terms[MAX_TERMS];
    Py_ssize_t nterms = 0;
    Pending obs_p = {0}, act_p = {0};

    episode = stream_attr(self, S_EPISODE);
    block = stream_attr(self, S_BLOCK);
    if (episode == NULL || block == NULL)
        goto python;
    if (!Py_IS_TYPE(episode, episode_type) || SLOT(episode, off_ep[E_ENDED]) != Py_False ||
        !Py_IS_TYPE(block, block_type))
        goto python;
    if (PyDict_GET_SIZE(info) && !read_terms(self, info, terms, &nterms, &names))
        goto python;
    PyObject *rewards = SLOT(block, off_rewards), *times = SLOT(block, off_times);
    PyObject *term_vals = SLOT(block, off_term_vals), *term_rows = SLOT(block, off_term_rows),
             *term_counts = SLOT(block, off_term_counts), *term_keys = SLOT(block, off_term_keys);
    if (!array_room(rewards, 1, 8) || !array_room(times, 1, 8))
        goto python;
    if (nterms && (!array_room(term_vals, nterms, 8) || !array_room(term_rows, 1, 8) ||
                   !array_room(term_counts, 1, 8) || !PyList_CheckExact(term_keys)))
        goto python;
    double r = PyFloat_AsDouble(reward);
    if (r == -1.0 && PyErr_Occurred())
        goto python;
    if (!plan_value(SLOT(block, off_obs), obs, &obs_p) ||
        !plan_value(SLOT(block, off_act), action, &act_p))
        goto python;
    long long now;
    Py_ssize_t row = Py_SIZE(times);
    if (row != obs_p.n || row != act_p.n || row != Py_SIZE(rewards))
        goto python; /* (columns not aligned: never, but the Python path would cope) */
    if (call_clock(self->clock, &now) < 0) /* (the stream's clock) */
        goto python;
    /* Everything checked: record the row (the time last: it commits the row). */
    if (nterms) {
        Py_ssize_t before = PyList_GET_SIZE(term_keys);
        if (PyList_SetSlice(term_keys, before, before, names) < 0)
            goto python;
    }
    commit_value(&obs_p);
    commit_value(&act_p);
    array_push_d(rewards, r);
    if (nterms) {
        array_push_q(term_rows, row);
        array_push_q(term_counts, nterms);
        for (Py_ssize_t j = 0; j < nterms; j++)
            array_push_d(term_vals, terms[j]);
    }
    array_push_q(times, now);
    self->compiled_steps++;
    Py_CLEAR(names);
    if ((terminated == Py_True || truncated == Py_True) &&
        end_by_flags(stream, episode, block, row, terminated, truncated, info) < 0)
        goto done;
    if (flush_after_step(self, now, row) < 0)
        goto done;
    ret = Py_NewRef(Py_None);
    goto done;
python:
    PyErr_Clear();
    Py_CLEAR(names);
    ret = python_step(self, action, result);
done:
    Py_XDECREF(obs_p.count); /* (a plan not committed) */
    Py_XDECREF(act_p.count);
    Py_XDECREF(names);
    Py_XDECREF(episode);
    Py_XDECREF(block);
    return ret;
}

/* ------------------------------------------------------------------ the reset

   A seeded reset of a stream with no open episode, as RecordEvidence.reset records it on the
   Python path: begin(seed) is EpisodeStream.begin(seed, None, None, []) (the reset's
   arguments: an int64 seed, no options) and reset_row(episode, result) is
   EpisodeStream.record_reset(episode, obs, info, [], None) followed by the flush when due.
   Each changes nothing and returns None when its case is not this one. */

/* The file's clock (EvidenceFile.clock, read as the Python path reads it): 0, or -1. */
static int read_file_clock(StepRecorder *self, long long *now)
{
    PyObject *clock = PyObject_GetAttr(self->file, s_file_clock);
    if (clock == NULL)
        return -1;
    int got = call_clock(clock, now);
    Py_DECREF(clock);
    return got;
}

/* A new Episode, as Episode(index, seed, rng_json, None, start_ns, env_index, agent) makes it:
   a new reference, or NULL with an error. */
static PyObject *new_episode(PyObject *index, PyObject *seed, PyObject *rng_json,
                             long long start_ns, PyObject *env_index, PyObject *agent)
{
    PyObject *values[EPISODE_SLOTS] = {0};
    PyObject *fresh = episode_type->tp_alloc(episode_type, 0);
    PyObject *start = PyLong_FromLongLong(start_ns);
    values[E_AFTER_END] = PyLong_FromLong(0);
    values[E_RET] = PyFloat_FromDouble(0.0);
    values[E_TOTALS] = PyDict_New();
    if (fresh == NULL || start == NULL || values[E_AFTER_END] == NULL || values[E_RET] == NULL ||
        values[E_TOTALS] == NULL) {
        for (int i = 0; i < EPISODE_SLOTS; i++)
            Py_XDECREF(values[i]);
        Py_XDECREF(fresh);
        Py_XDECREF(start);
        return NULL;
    }
    values[E_AGENT] = Py_NewRef(agent);
    values[E_END_NS] = Py_NewRef(start);
    values[E_ENDED] = Py_NewRef(Py_False);
    values[E_ENV_INDEX] = Py_NewRef(env_index);
    values[E_GAME] = Py_NewRef(Py_None);
    values[E_INDEX] = Py_NewRef(index);
    values[E_NOTES] = Py_NewRef(values[E_AFTER_END]);
    values[E_OPTIONS] = Py_NewRef(Py_None);
    values[E_OPTIONS_JSON] = Py_NewRef(Py_None);
    values[E_RNG_JSON] = Py_NewRef(rng_json);
    values[E_SEED] = Py_NewRef(seed);
    values[E_START_NS] = start; /* (the reference made here) */
    values[E_STEPS] = Py_NewRef(values[E_AFTER_END]);
    for (int i = 0; i < EPISODE_SLOTS; i++)
        SLOT(fresh, off_ep[i]) = values[i];
    return fresh;
}

static PyObject *StepRecorder_begin(StepRecorder *self, PyObject *seed)
{
    PyObject *stream = self->stream, *episode = NULL, *block = NULL, *next = NULL,
             *env_index = NULL, *agent = NULL, *ret = NULL, *fresh = NULL, *next_after = NULL,
             *segment = NULL;
    if (!PyLong_CheckExact(seed))
        Py_RETURN_NONE;
    int overflow = 0;
    long long number = PyLong_AsLongLongAndOverflow(seed, &overflow);
    if (overflow || number < 0) { /* (-1 with an error cannot happen for an exact int) */
        PyErr_Clear();
        Py_RETURN_NONE;
    }
    episode = stream_attr(self, S_EPISODE);
    block = episode == NULL ? NULL : stream_attr(self, S_BLOCK);
    next = block == NULL ? NULL : PyObject_GetAttr(self->file, s_next_episode);
    env_index = next == NULL ? NULL : PyObject_GetAttr(stream, s_env_index);
    agent = env_index == NULL ? NULL : PyObject_GetAttr(stream, s_agent);
    if (agent == NULL)
        goto done;
    if (episode != Py_None && (!Py_IS_TYPE(episode, episode_type) ||
                               SLOT(episode, off_ep[E_ENDED]) != Py_True))
        goto decline; /* an open episode: ended as incomplete by the Python path */
    if (!Py_IS_TYPE(block, block_type) || !PyLong_CheckExact(next))
        goto decline;
    PyObject *segments = SLOT(block, off_segments), *episodes = SLOT(block, off_episodes),
             *times = SLOT(block, off_times), *pending = SLOT(block, off_pending);
    if (segments == NULL || episodes == NULL || times == NULL || pending == NULL ||
        !PyList_CheckExact(segments) || !PyDict_CheckExact(episodes) ||
        !Py_IS_TYPE(times, array_type) || !PyLong_CheckExact(pending))
        goto decline;
    Py_ssize_t waiting = PyLong_AsSsize_t(pending), index = PyLong_AsSsize_t(next);
    if (waiting < 0 || index < 0 || index == PY_SSIZE_T_MAX)
        goto decline;
    long long now;
    if (read_file_clock(self, &now) < 0)
        goto done;
    /* Everything made before anything changes. */
    next_after = PyLong_FromSsize_t(index + 1);
    segment = Py_BuildValue("(nOiO)", Py_SIZE(times) + waiting, next, 0, Py_True);
    fresh = next_after == NULL || segment == NULL
                ? NULL
                : new_episode(next, seed, Py_None, now, env_index, agent);
    if (fresh == NULL)
        goto done;
    untrack(fresh);
    untrack(segment);
    /* The file's next index first: if that fails, nothing else has changed. */
    if (PyObject_SetAttr(self->file, s_next_episode, next_after) < 0 ||
        PyList_Append(segments, segment) < 0 || PyDict_SetItem(episodes, next, fresh) < 0 ||
        PyObject_SetAttr(stream, s_episode, fresh) < 0)
        goto done;
    ret = Py_NewRef(fresh);
    goto done;
decline:
    PyErr_Clear();
    ret = Py_NewRef(Py_None);
done:
    Py_XDECREF(episode);
    Py_XDECREF(block);
    Py_XDECREF(next);
    Py_XDECREF(env_index);
    Py_XDECREF(agent);
    Py_XDECREF(fresh);
    Py_XDECREF(next_after);
    Py_XDECREF(segment);
    return ret;
}

static PyObject *StepRecorder_reset_row(StepRecorder *self, PyObject *const *args,
                                        Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "reset_row(episode, result): two arguments");
        return NULL;
    }
    PyObject *episode = args[0], *result = args[1], *block = NULL, *row = NULL, *ret = NULL;
    Pending obs_p = {0};
    if (!Py_IS_TYPE(episode, episode_type) || !PyTuple_CheckExact(result) ||
        PyTuple_GET_SIZE(result) != 2 || !PyDict_CheckExact(PyTuple_GET_ITEM(result, 1)) ||
        SLOT(episode, off_ep[E_RNG_JSON]) != Py_None)
        Py_RETURN_NONE;
    block = stream_attr(self, S_BLOCK);
    if (block == NULL)
        return NULL;
    PyObject *resets = SLOT(block, off_resets);
    if (!Py_IS_TYPE(block, block_type) || resets == NULL || !PyList_CheckExact(resets) ||
        !plan_value(SLOT(block, off_reset_obs), PyTuple_GET_ITEM(result, 0), &obs_p) ||
        obs_p.n != PyList_GET_SIZE(resets))
        goto decline;
    long long now;
    if (read_file_clock(self, &now) < 0)
        goto done;
    row = PyTuple_Pack(7, SLOT(episode, off_ep[E_INDEX]), SLOT(episode, off_ep[E_START_NS]),
                       SLOT(episode, off_ep[E_SEED]), Py_None,
                       SLOT(episode, off_ep[E_OPTIONS_JSON]), SLOT(episode, off_ep[E_GAME]),
                       Py_None);
    if (row == NULL || PyList_Append(resets, row) < 0)
        goto done;
    untrack(row);
    commit_value(&obs_p);
    self->compiled_resets++;
    if (flush_if_due(self, now, 0) < 0)
        goto done;
    ret = Py_NewRef(Py_True);
    goto done;
decline:
    PyErr_Clear();
    ret = Py_NewRef(Py_None);
done:
    Py_XDECREF(obs_p.count);
    Py_XDECREF(block);
    Py_XDECREF(row);
    return ret;
}

static PyMethodDef StepRecorder_methods[] = {
    {"begin", (PyCFunction)StepRecorder_begin, METH_O,
     "begin(seed): the stream's new Episode for a reset with this seed and no options, or "
     "None (nothing changed: the Python path decides)."},
    {"reset_row", (PyCFunction)(void (*)(void))StepRecorder_reset_row, METH_FASTCALL,
     "reset_row(episode, result): record the reset row of the episode begin() made and flush "
     "when due: True, or None (nothing changed: the Python path decides)."},
    {NULL}};

static PyObject *StepRecorder_vectorcall(PyObject *callable, PyObject *const *args,
                                         size_t nargsf, PyObject *kwnames)
{
    if (PyVectorcall_NARGS(nargsf) != 2 || kwnames != NULL) {
        PyErr_SetString(PyExc_TypeError, "StepRecorder(action, result): two arguments");
        return NULL;
    }
    return step_impl((StepRecorder *)callable, args[0], args[1]);
}

static PyObject *StepRecorder_new(PyTypeObject *type, PyObject *args, PyObject *kwargs)
{
    PyObject *stream;
    static char *kw[] = {"stream", NULL};
    if (!configured) {
        PyErr_SetString(PyExc_RuntimeError, "_stepfast.configure() was not called");
        return NULL;
    }
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "O:StepRecorder", kw, &stream))
        return NULL;
    StepRecorder *self = (StepRecorder *)type->tp_alloc(type, 0);
    if (self == NULL)
        return NULL;
    self->vectorcall = StepRecorder_vectorcall;
    self->stream = Py_NewRef(stream);
    for (int i = 0; i < S_COUNT; i++) {
        self->stream_off[i] = member_offset(Py_TYPE(stream), *stream_names[i]);
        if (self->stream_off[i] < 0 && PyErr_Occurred()) {
            Py_DECREF(self);
            return NULL;
        }
    }
    self->fallback = PyObject_GetAttr(stream, s_step);
    self->file = self->fallback ? PyObject_GetAttr(stream, s_file) : NULL;
    self->clock = self->file ? PyObject_GetAttr(stream, s_clock) : NULL;
    if (self->clock == NULL) {
        Py_DECREF(self);
        return NULL;
    }
    return (PyObject *)self;
}

static int StepRecorder_traverse(StepRecorder *self, visitproc visit, void *arg)
{
    Py_VISIT(self->stream);
    Py_VISIT(self->fallback);
    Py_VISIT(self->file);
    Py_VISIT(self->clock);
    return 0;
}

static int StepRecorder_clear(StepRecorder *self)
{
    Py_CLEAR(self->stream);
    Py_CLEAR(self->fallback);
    Py_CLEAR(self->file);
    Py_CLEAR(self->clock);
    return 0;
}

static void StepRecorder_dealloc(StepRecorder *self)
{
    PyObject_GC_UnTrack(self);
    StepRecorder_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyObject *StepRecorder_call(PyObject *self, PyObject *args, PyObject *kwargs)
{
    PyObject *action, *result;
    if (kwargs != NULL && PyDict_GET_SIZE(kwargs)) {
        PyErr_SetString(PyExc_TypeError, "StepRecorder(action, result): two arguments");
        return NULL;
    }
    if (!PyArg_ParseTuple(args, "OO:StepRecorder", &action, &result))
        return NULL;
    return step_impl((StepRecorder *)self, action, result);
}

static PyMemberDef StepRecorder_members[] = {
    {"stream", T_OBJECT_EX, offsetof(StepRecorder, stream), READONLY, "The stream recorded."},
    {"compiled_steps", T_PYSSIZET, offsetof(StepRecorder, compiled_steps), READONLY,
     "Steps recorded by the compiled path."},
    {"python_steps", T_PYSSIZET, offsetof(StepRecorder, python_steps), READONLY,
     "Steps handed to the Python path."},
    {"compiled_resets", T_PYSSIZET, offsetof(StepRecorder, compiled_resets), READONLY,
     "Resets recorded by the compiled path (begin and reset_row)."},
    {NULL}};

static PyTypeObject StepRecorderType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "episode_audit.record._stepfast.StepRecorder",
    .tp_basicsize = sizeof(StepRecorder),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC | Py_TPFLAGS_HAVE_VECTORCALL,
    .tp_doc = "StepRecorder(stream): stream.step(action, result), compiled for the common step.",
    .tp_new = StepRecorder_new,
    .tp_traverse = (traverseproc)StepRecorder_traverse,
    .tp_clear = (inquiry)StepRecorder_clear,
    .tp_dealloc = (destructor)StepRecorder_dealloc,
    .tp_call = StepRecorder_call,
    .tp_vectorcall_offset = offsetof(StepRecorder, vectorcall),
    .tp_members = StepRecorder_members,
    .tp_methods = StepRecorder_methods,
};

/* ------------------------------------------------------------------ episode records

   episode_json(ended, offset, games, quote, to_json) writes the JSON records of the ended
   episodes (the file's pending list of (Episode, ending dict)) as episode_records._episode_json
   does, and their end times. Only the common record is written here, the one
   episode_records._plain_episode_json writes: no error, no options, a finite float return, int fields, str texts. If any episode
   is another, it returns None and the Python path writes them all. Texts that are not plain
   printable ASCII are quoted by `quote` (json's encode_basestring_ascii), term totals by
   `to_json`: the same bytes, made where they are made in Python. */

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
    if (PyDict_GET_SIZE(totals) == 0) {
        if (!text_put(t, "{}", 2))
            return -1;
    }
    else {
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

static PyObject *episode_json(PyObject *module, PyObject *args)
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

static PyObject *episode_columns(PyObject *module, PyObject *args)
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
static PyObject *rng_json(PyObject *module, PyObject *args)
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
static PyObject *frame_messages(PyObject *module, PyObject *args)
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

/* ------------------------------------------------------------------ vector batches

   vector_step(obs_rows, act_rows, rew_rows, time_rows, t, obs, actions, rewards, terminated,
   truncated, clock, endings_ok) writes a vector step into row t of the vector recorder's batch
   buffers as VectorSteps._batch_step does (steps.py): the observations and actions copied as
   they are, the rewards as float64, the time read from `clock`. It takes the step only when
   each value is an array numpy would store there unchanged: observations and actions of the
   buffers' numeric dtype and row shape, C-contiguous; rewards a 1-D array of numbers, one per
   sub-env; flags 1-D bool arrays. Then it returns (time, the sub-envs whose episodes the step
   ended). Otherwise (or when a step that ends an episode is not `endings_ok`) it returns None,
   having read no clock and written nothing: the Python path takes the step. */

/* Whether `a` is an exact, aligned, native-order numeric (or bool) array. */
static int plain_numbers(PyObject *a)
{
    if (!PyArray_CheckExact(a))
        return 0;
    PyArrayObject *arr = (PyArrayObject *)a;
    int type = PyArray_TYPE(arr);
    return (PyTypeNum_ISNUMBER(type) || PyTypeNum_ISBOOL(type)) && PyArray_ISALIGNED(arr) &&
           PyArray_ISNOTSWAPPED(arr);
}

/* Whether `value` fits row `t` of `rows` as it is: the same dtype, the row's shape, both
   C-contiguous and `rows` writeable. */
static int fits_row(PyArrayObject *rows, PyObject *value, Py_ssize_t t)
{
    if (!plain_numbers((PyObject *)rows) || !plain_numbers(value))
        return 0;
    PyArrayObject *v = (PyArrayObject *)value;
    int nd = PyArray_NDIM(v);
    if (PyArray_NDIM(rows) != nd + 1 || t < 0 || t >= PyArray_DIM(rows, 0) ||
        !PyArray_EquivTypes(PyArray_DESCR(rows), PyArray_DESCR(v)) ||
        PyArray_TYPE(rows) != PyArray_TYPE(v) || !PyArray_IS_C_CONTIGUOUS(rows) ||
        !PyArray_IS_C_CONTIGUOUS(v) || !PyArray_ISWRITEABLE(rows))
        return 0;
    for (int d = 0; d < nd; d++)
        if (PyArray_DIM(v, d) != PyArray_DIM(rows, d + 1))
            return 0;
    return 1;
}

/* Whether `a` is a 1-D bool array of `n`. */
static int bool_flags(PyObject *a, Py_ssize_t n)
{
    return PyArray_CheckExact(a) && PyArray_TYPE((PyArrayObject *)a) == NPY_BOOL &&
           PyArray_NDIM((PyArrayObject *)a) == 1 && PyArray_DIM((PyArrayObject *)a, 0) == n;
}

/* Element `i` of the 1-D numeric array `a` as a double (numpy's cast); 0 for a dtype not
   read here (with *ok cleared). */
static double number_at(PyArrayObject *a, Py_ssize_t i, int *ok)
{
    const char *p = PyArray_BYTES(a) + i * PyArray_STRIDE(a, 0);
    switch (PyArray_TYPE(a)) {
    case NPY_DOUBLE: return *(const npy_double *)p;
    case NPY_FLOAT: return *(const npy_float *)p;
    case NPY_BOOL: return *(const npy_bool *)p ? 1.0 : 0.0;
    case NPY_BYTE: return *(const npy_byte *)p;
    case NPY_UBYTE: return *(const npy_ubyte *)p;
    case NPY_SHORT: return *(const npy_short *)p;
    case NPY_USHORT: return *(const npy_ushort *)p;
    case NPY_INT: return *(const npy_int *)p;
    case NPY_UINT: return *(const npy_uint *)p;
    case NPY_LONG: return (double)*(const npy_long *)p;
    case NPY_ULONG: return (double)*(const npy_ulong *)p;
    case NPY_LONGLONG: return (double)*(const npy_longlong *)p;
    case NPY_ULONGLONG: return (double)*(const npy_ulonglong *)p;
    default: *ok = 0; return 0.0;
    }
}

static PyObject *vector_step(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 12) {
        PyErr_SetString(PyExc_TypeError, "vector_step: twelve arguments");
        return NULL;
    }
    PyObject *obs_rows = args[0], *act_rows = args[1], *rew_rows = args[2],
             *time_rows = args[3], *obs = args[5], *actions = args[6], *rewards = args[7],
             *term = args[8], *trunc = args[9];
    Py_ssize_t t = PyLong_AsSsize_t(args[4]);
    int endings_ok = PyObject_IsTrue(args[11]);
    long long now;
    if ((t == -1 || endings_ok < 0) && PyErr_Occurred())
        return NULL;
    if (!PyArray_CheckExact(rew_rows) || !PyArray_CheckExact(time_rows) ||
        !fits_row((PyArrayObject *)obs_rows, obs, t) ||
        !fits_row((PyArrayObject *)act_rows, actions, t))
        Py_RETURN_NONE;
    PyArrayObject *rr = (PyArrayObject *)rew_rows, *tr = (PyArrayObject *)time_rows,
                  *rw = (PyArrayObject *)rewards;
    if (PyArray_NDIM(rr) != 2 || PyArray_TYPE(rr) != NPY_DOUBLE || !PyArray_ISNOTSWAPPED(rr) ||
        !PyArray_IS_C_CONTIGUOUS(rr) || !PyArray_ISWRITEABLE(rr) || PyArray_DIM(rr, 0) <= t ||
        PyArray_NDIM(tr) != 1 || PyArray_TYPE(tr) != NPY_INT64 || !PyArray_ISNOTSWAPPED(tr) ||
        !PyArray_ISWRITEABLE(tr) || PyArray_DIM(tr, 0) <= t)
        Py_RETURN_NONE;
    Py_ssize_t n = PyArray_DIM(rr, 1);
    if (!plain_numbers(rewards) || PyArray_NDIM(rw) != 1 || PyArray_DIM(rw, 0) != n ||
        !bool_flags(term, n) || !bool_flags(trunc, n) || n > PY_SSIZE_T_MAX / 8)
        Py_RETURN_NONE;
    double *rew_row = (double *)(PyArray_BYTES(rr) + t * PyArray_STRIDE(rr, 0));
    double stack[64], *values = n <= 64 ? stack : PyMem_Malloc(n * sizeof(double));
    if (values == NULL)
        return PyErr_NoMemory();
    PyObject *ends = PyList_New(0);
    int ok = ends != NULL, ended = 0;
    const char *te = PyArray_BYTES((PyArrayObject *)term), *tu = PyArray_BYTES((PyArrayObject *)trunc);
    npy_intp ts = PyArray_STRIDE((PyArrayObject *)term, 0),
             us = PyArray_STRIDE((PyArrayObject *)trunc, 0);
    for (Py_ssize_t i = 0; ok && i < n; i++) {
        values[i] = number_at(rw, i, &ok);
        if (ok && (te[i * ts] || tu[i * us])) {
            PyObject *index = PyLong_FromSsize_t(i);
            ok = index != NULL && PyList_Append(ends, index) == 0;
            Py_XDECREF(index);
            ended = 1;
        }
    }
    PyObject *ret = NULL;
    if (ends == NULL || PyErr_Occurred()) {
        ;
    } else if (!ok || (ended && !endings_ok)) {
        ret = Py_NewRef(Py_None);
    } else if (call_clock(args[10], &now) == 0 && (ret = Py_BuildValue("(LO)", now, ends))) {
        /* taken: nothing can fail from here (memmove: a value may be a view of its buffer) */
        memcpy(rew_row, values, n * sizeof(double));
        memmove(PyArray_BYTES((PyArrayObject *)obs_rows) +
                   t * PyArray_STRIDE((PyArrayObject *)obs_rows, 0),
               PyArray_BYTES((PyArrayObject *)obs), PyArray_NBYTES((PyArrayObject *)obs));
        memmove(PyArray_BYTES((PyArrayObject *)act_rows) +
                   t * PyArray_STRIDE((PyArrayObject *)act_rows, 0),
               PyArray_BYTES((PyArrayObject *)actions), PyArray_NBYTES((PyArrayObject *)actions));
        *(npy_int64 *)(PyArray_BYTES(tr) + t * PyArray_STRIDE(tr, 0)) = now;
    }
    if (values != stack)
        PyMem_Free(values);
    Py_XDECREF(ends);
    return ret;
}


/* end_batched(stream, pending, terminated, truncated, info): a batched vector step ended the
   stream's episode. As VectorSteps._batched does it in Python: the stream's block counts
   `pending` rows batched for it (set here, always), then the open episode, if any, ends by
   the flags of its last row as EpisodeStream.end_step ends it (its plain ending recorded
   here, any other by the stream's _end_by_flags). None. (The episode is None or an Episode:
   EpisodeStream sets no other.) */
static PyObject *end_batched(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "end_batched: five arguments");
        return NULL;
    }
    PyObject *stream = args[0], *pending = args[1], *terminated = args[2],
             *truncated = args[3], *info = args[4], *block = NULL, *episode = NULL,
             *ret = NULL;
    if (!PyLong_CheckExact(pending) || !PyBool_Check(terminated) || !PyBool_Check(truncated) ||
        !PyDict_CheckExact(info)) {
        PyErr_SetString(PyExc_TypeError, "end_batched(stream, int, bool, bool, dict)");
        return NULL;
    }
    Py_ssize_t waiting = PyLong_AsSsize_t(pending);
    if (waiting == -1 && PyErr_Occurred())
        return NULL;
    block = PyObject_GetAttr(stream, s_block);
    episode = block == NULL ? NULL : PyObject_GetAttr(stream, s_episode);
    if (episode == NULL)
        goto done;
    PyObject *times = Py_IS_TYPE(block, block_type) ? SLOT(block, off_times) : NULL;
    if (times == NULL || !Py_IS_TYPE(times, array_type)) {
        PyErr_SetString(PyExc_TypeError, "end_batched: the stream's block is not a Block");
        goto done;
    }
    Py_SETREF(SLOT(block, off_pending), Py_NewRef(pending));
    if (Py_IS_TYPE(episode, episode_type) && SLOT(episode, off_ep[E_ENDED]) == Py_False &&
        end_by_flags(stream, episode, block, Py_SIZE(times) + waiting - 1, terminated,
                     truncated, info) < 0)
        goto done;
    ret = Py_NewRef(Py_None);
done:
    Py_XDECREF(block);
    Py_XDECREF(episode);
    return ret;
}


/* begin_autoreset(stream, rng_json, obs, start_ns): a NEXT_STEP autoreset of a vector
   recorder's sub-env, with no info, as NextStep.autoreset records it: the stream's next
   Episode (no seed, no options; `rng_json` the RNG state it reset from, as JSON bytes)
   begun at `start_ns`, and its reset row with the observation `obs`. True; or None when the
   stream has an open episode or `obs` does not go into the reset column as it is (nothing
   changed: the Python path records it). The stream keeps no info (the caller checks). */
static PyObject *begin_autoreset(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "begin_autoreset: four arguments");
        return NULL;
    }
    PyObject *stream = args[0], *rng_json = args[1], *obs = args[2], *start = args[3];
    PyObject *file = NULL, *episode = NULL, *block = NULL, *next = NULL, *env_index = NULL,
             *agent = NULL, *text = NULL, *next_after = NULL, *segment = NULL, *fresh = NULL,
             *row = NULL, *ret = NULL;
    Pending obs_p = {0};
    long long start_ns;
    if (!PyBytes_CheckExact(rng_json) || !PyLong_CheckExact(start) ||
        as_long_long(start, &start_ns) < 0)
        goto decline;
    file = PyObject_GetAttr(stream, s_file);
    episode = file == NULL ? NULL : PyObject_GetAttr(stream, s_episode);
    block = episode == NULL ? NULL : PyObject_GetAttr(stream, s_block);
    next = block == NULL ? NULL : PyObject_GetAttr(file, s_next_episode);
    env_index = next == NULL ? NULL : PyObject_GetAttr(stream, s_env_index);
    agent = env_index == NULL ? NULL : PyObject_GetAttr(stream, s_agent);
    if (agent == NULL)
        goto done;
    if (episode != Py_None && (!Py_IS_TYPE(episode, episode_type) ||
                               SLOT(episode, off_ep[E_ENDED]) != Py_True))
        goto decline; /* an open episode: ended as incomplete by the Python path */
    if (!Py_IS_TYPE(block, block_type) || !PyLong_CheckExact(next))
        goto decline;
    PyObject *segments = SLOT(block, off_segments), *episodes = SLOT(block, off_episodes),
             *times = SLOT(block, off_times), *pending = SLOT(block, off_pending),
             *resets = SLOT(block, off_resets);
    if (segments == NULL || episodes == NULL || times == NULL || pending == NULL ||
        resets == NULL || !PyList_CheckExact(segments) || !PyDict_CheckExact(episodes) ||
        !Py_IS_TYPE(times, array_type) || !PyLong_CheckExact(pending) ||
        !PyList_CheckExact(resets))
        goto decline;
    Py_ssize_t waiting = PyLong_AsSsize_t(pending), index = PyLong_AsSsize_t(next);
    if (waiting < 0 || index < 0 || index == PY_SSIZE_T_MAX)
        goto decline;
    if (!plan_value(SLOT(block, off_reset_obs), obs, &obs_p) ||
        obs_p.n != PyList_GET_SIZE(resets))
        goto decline;
    text = PyUnicode_DecodeUTF8(PyBytes_AS_STRING(rng_json), PyBytes_GET_SIZE(rng_json), NULL);
    if (text == NULL)
        goto decline;
    /* Everything made before anything changes. */
    next_after = PyLong_FromSsize_t(index + 1);
    segment = Py_BuildValue("(nOiO)", Py_SIZE(times) + waiting, next, 0, Py_True);
    fresh = next_after == NULL || segment == NULL
                ? NULL
                : new_episode(next, Py_None, rng_json, start_ns, env_index, agent);
    row = fresh == NULL ? NULL
                        : PyTuple_Pack(7, next, SLOT(fresh, off_ep[E_START_NS]), Py_None, text,
                                       Py_None, Py_None, Py_None);
    if (row == NULL)
        goto done;
    untrack(fresh);
    untrack(segment);
    untrack(row);
    /* The file's next index first: if that fails, nothing else has changed. */
    if (PyObject_SetAttr(file, s_next_episode, next_after) < 0 ||
        PyObject_SetAttr(stream, s_episode, fresh) < 0 || PyList_Append(segments, segment) < 0 ||
        PyDict_SetItem(episodes, next, fresh) < 0 || PyList_Append(resets, row) < 0)
        goto done;
    commit_value(&obs_p);
    ret = Py_NewRef(Py_True);
    goto done;
decline:
    PyErr_Clear();
    ret = Py_NewRef(Py_None);
done:
    Py_XDECREF(obs_p.count);
    Py_XDECREF(file);
    Py_XDECREF(episode);
    Py_XDECREF(block);
    Py_XDECREF(next);
    Py_XDECREF(env_index);
    Py_XDECREF(agent);
    Py_XDECREF(text);
    Py_XDECREF(next_after);
    Py_XDECREF(segment);
    Py_XDECREF(fresh);
    Py_XDECREF(row);
    return ret;
}

/* ------------------------------------------------------------------ configure */

/* Episode's __slots__ are those of episode_slots, and their offsets are read. */
static int episode_layout_ok(void)
{
    PyObject *names = PyObject_GetAttr((PyObject *)episode_type, s_slots);
    if (names == NULL)
        return 0;
    int same = PyTuple_Check(names) && PyTuple_GET_SIZE(names) == EPISODE_SLOTS;
    Py_DECREF(names);
    if (!same) {
        PyErr_SetString(PyExc_TypeError, "Episode's slots are not those compiled in");
        return 0;
    }
    for (int i = 0; i < EPISODE_SLOTS; i++)
        if ((off_ep[i] = slot_offset(episode_type, episode_slots[i])) < 0)
            return 0;
    return 1;
}

static PyObject *configure(PyObject *module, PyObject *args)
{
    PyObject *types[6];
    if (!PyArg_ParseTuple(args, "O!O!O!O!O!O!:configure", &PyType_Type, &types[0], &PyType_Type,
                          &types[1], &PyType_Type, &types[2], &PyType_Type, &types[3],
                          &PyType_Type, &types[4], &PyType_Type, &types[5]))
        return NULL;
    int layout = layout_ok();
    if (layout < 0)
        return NULL;
    if (!layout) {
        PyErr_SetString(PyExc_RuntimeError, "array.array's layout is not the one compiled in");
        return NULL;
    }
    block_type = (PyTypeObject *)types[0];
    episode_type = (PyTypeObject *)types[1];
    flat_type = (PyTypeObject *)types[2];
    nd_type = (PyTypeObject *)types[3];
    int_type = (PyTypeObject *)types[4];
    array_type = (PyTypeObject *)types[5];
    for (int i = 0; i < 6; i++)
        Py_INCREF(types[i]);
    struct {
        PyTypeObject *type;
        const char *name;
        Py_ssize_t *offset;
    } slots[] = {
        {block_type, "ends", &off_ends},
        {block_type, "flags", &off_flags},
        {block_type, "segments", &off_segments},
        {block_type, "episodes", &off_episodes},
        {block_type, "pending", &off_pending},
        {block_type, "reset_obs", &off_reset_obs},
        {block_type, "resets", &off_resets},
        {block_type, "obs", &off_obs},
        {block_type, "act", &off_act},
        {block_type, "rewards", &off_rewards},
        {block_type, "times", &off_times},
        {block_type, "term_vals", &off_term_vals},
        {block_type, "term_rows", &off_term_rows},
        {block_type, "term_counts", &off_term_counts},
        {block_type, "term_keys", &off_term_keys},
        {nd_type, "_data", &off_arr_data},
        {nd_type, "_n", &off_arr_n},
        {nd_type, "_dtype", &off_arr_dtype},
        {int_type, "_data", &off_int_data},
        {int_type, "_n", &off_int_n},
    };
    for (size_t i = 0; i < sizeof(slots) / sizeof(slots[0]); i++) {
        *slots[i].offset = slot_offset(slots[i].type, slots[i].name);
        if (*slots[i].offset < 0)
            return NULL;
    }
    if (!episode_layout_ok())
        return NULL;
    /* the flat buffer is a subclass of the n-d one: the same slots, at the same offsets */
    if (slot_offset(flat_type, "_data") != off_arr_data || slot_offset(flat_type, "_n") != off_arr_n ||
        slot_offset(flat_type, "_dtype") != off_arr_dtype) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_TypeError, "the flat buffer's slots differ from the n-d one's");
        return NULL;
    }
    configured = 1;
    Py_RETURN_NONE;
}

static PyMethodDef module_methods[] = {
    {"configure", configure, METH_VARARGS,
     "configure(Block, Episode, FlatArrayBuffer, ArrayBuffer, IntBuffer, array.array)"},
    {"episode_json", episode_json, METH_VARARGS,
     "episode_json(ended, offset, games, quote, to_json): ([record JSON], [end time]) or None"},
    {"episode_columns", episode_columns, METH_VARARGS,
     "episode_columns(ended, offset, games): the episode block's columns, or None"},
    {"rng_json", rng_json, METH_VARARGS, "rng_json(state, quote): to_json(state), or None"},
    {"untrack", untrack_object, METH_O,
     "untrack(obj): leave obj out of the cyclic collector (native.untrack: which objects)"},
    {"vector_step", (PyCFunction)(void (*)(void))vector_step, METH_FASTCALL,
     "vector_step(obs_rows, act_rows, rew_rows, time_rows, t, obs, actions, rewards, "
     "terminated, truncated, clock, endings_ok): (time, ended sub-envs), or None (not taken)"},
    {"end_batched", (PyCFunction)(void (*)(void))end_batched, METH_FASTCALL,
     "end_batched(stream, pending, terminated, truncated, info): a batched step's ending"},
    {"begin_autoreset", (PyCFunction)(void (*)(void))begin_autoreset, METH_FASTCALL,
     "begin_autoreset(stream, rng_json, obs, start_ns): True, or None (not taken)"},
    {"frame_messages", frame_messages, METH_VARARGS,
     "frame_messages(datas, times, channel, sequence, offset): (records, index entries)"},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module_def = {
    PyModuleDef_HEAD_INIT, "_stepfast",
    "The recorder's per-step path, compiled (episode_audit.record.fast uses it).", -1,
    module_methods};

#define INTERN(var, text)                                                                          \
    do {                                                                                           \
        if ((var = PyUnicode_InternFromString(text)) == NULL)                                      \
            return NULL;                                                                           \
    } while (0)

PyMODINIT_FUNC PyInit__stepfast(void)
{
    import_array();
    INTERN(s_episode, "episode");
    INTERN(s_block, "block");
    INTERN(s_terms_keys, "_terms_keys");
    INTERN(s_terms_names, "_terms_names");
    INTERN(s_block_steps, "_block_steps");
    INTERN(s_file, "file");
    INTERN(s_flush_at, "flush_at");
    INTERN(s_end_by_flags, "_end_by_flags");
    INTERN(s_auto_flush, "auto_flush");
    INTERN(s_step, "step");
    INTERN(s_clock, "_clock");
    INTERN(s_flag_endings, "_flag_endings");
    INTERN(s_ending_keys, "_ending_keys");
    INTERN(s_limit_hit, "_limit_hit");
    INTERN(s_pending, "pending");
    INTERN(s_counts, "counts");
    INTERN(s_episodes, "episodes");
    INTERN(s_outcome, "outcome");
    INTERN(s_failure_label, "failure_label");
    INTERN(s_truncation_reason, "truncation_reason");
    INTERN(s_terminated, "terminated");
    INTERN(s_truncated, "truncated");
    INTERN(s_error, "error");
    INTERN(s_time_limit, "_time_limit");
    INTERN(s_elapsed_steps, "_elapsed_steps");
    INTERN(s_max_episode_steps, "_max_episode_steps");
    INTERN(s_next_episode, "next_episode");
    INTERN(s_env_index, "env_index");
    INTERN(s_agent, "agent");
    INTERN(s_slots, "__slots__");
    INTERN(s_file_clock, "clock");
    INTERN(s_error_ns, "error_ns");
    PyObject *time = PyImport_ImportModule("time");
    if (time == NULL)
        return NULL;
    monotonic_ns = PyObject_GetAttrString(time, "monotonic_ns");
    Py_DECREF(time);
    if (monotonic_ns == NULL || PyType_Ready(&StepRecorderType) < 0)
        return NULL;
    PyObject *module = PyModule_Create(&module_def);
    if (module == NULL)
        return NULL;
    if (PyModule_AddObjectRef(module, "StepRecorder", (PyObject *)&StepRecorderType) < 0) {
        Py_DECREF(module);
        return NULL;
    }
    return module;
}
