/* The single-env step and reset, compiled: StepRecorder (module.c says how it is used). */

#include "stepfast.h"

/* ------------------------------------------------------------------ column buffers */

/* Whether `value` goes into `buffer` as its Python append would take it without a note, and
   the buffer's block has room: 1 (filled `p`), 0 (the Python path decides). */
int plan_value(PyObject *buffer, PyObject *value, Pending *p)
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
void commit_value(Pending *p)
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
int as_long_long(PyObject *value, long long *out)
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
int call_clock(PyObject *clock, long long *now)
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
    Py_ssize_t pos = 0, i = 0, n = PyTuple_GET_SIZE(keys);
    PyObject *key, *value, *seen[MAX_TERMS]; /* (the values in the keys' order) */
    while (PyDict_Next(info, &pos, &key, &value)) {
        PyObject *planned = PyTuple_GET_ITEM(keys, i);
        if (key != planned) {
            int same = PyObject_RichCompareBool(key, planned, Py_EQ);
            if (same != 1)
                goto done;
        }
        if (i < MAX_TERMS)
            seen[i] = value;
        i++;
    }
    names = stream_attr(self, S_TERMS_NAMES);
    if (names == NULL || !PyTuple_CheckExact(names) || PyTuple_GET_SIZE(names) > MAX_TERMS)
        goto done;
    Py_ssize_t k = PyTuple_GET_SIZE(names);
    for (Py_ssize_t j = 0; j < k; j++) {
        PyObject *name = PyTuple_GET_ITEM(names, j), *term = NULL;
        for (Py_ssize_t at = 0; at < n && at < MAX_TERMS && term == NULL; at++)
            if (PyTuple_GET_ITEM(keys, at) == name) /* (the plan's own strings: no hashing) */
                term = seen[at];
        if (term == NULL)
            term = PyDict_GetItemWithError(info, name);
        /* (an array, a tensor: number() decides) */
        if (term == NULL || number_value(term, &values[j]) != 1)
            goto done;
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
int end_by_flags(PyObject *stream, PyObject *episode, PyObject *block, Py_ssize_t row,
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
    double r;
    if (number_value(reward, &r) != 1) /* (an array, a tensor: number() decides) */
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
PyObject *new_episode(PyObject *index, PyObject *seed, PyObject *rng_json,
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
    values[E_OPTIONS_TYPED] = Py_NewRef(Py_None);
    values[E_RNG_JSON] = Py_NewRef(rng_json);
    values[E_SEED] = Py_NewRef(seed);
    values[E_START_NS] = start; /* (the reference made here) */
    values[E_STEPS] = Py_NewRef(values[E_AFTER_END]);
    for (int i = 0; i < EPISODE_SLOTS; i++)
        SLOT(fresh, off_ep[i]) = values[i];
    return fresh;
}

/* What beginning a stream's next episode reads (begin_read), checked, and makes (begin_make)
   before it changes anything (begin_apply), as EpisodeStream.begin does. */

int begin_read(Beginning *b)
{
    b->next = PyObject_GetAttr(b->file, s_next_episode);
    b->env_index = b->next == NULL ? NULL : PyObject_GetAttr(b->stream, s_env_index);
    b->agent = b->env_index == NULL ? NULL : PyObject_GetAttr(b->stream, s_agent);
    if (b->agent == NULL)
        return -1;
    PyObject *episode = b->episode, *block = b->block;
    if (episode != Py_None && (!Py_IS_TYPE(episode, episode_type) ||
                               SLOT(episode, off_ep[E_ENDED]) != Py_True))
        return 0; /* an open episode: ended as incomplete by the Python path */
    if (!Py_IS_TYPE(block, block_type) || !PyLong_CheckExact(b->next))
        return 0;
    PyObject *pending = SLOT(block, off_pending);
    b->segments = SLOT(block, off_segments);
    b->episodes = SLOT(block, off_episodes);
    b->times = SLOT(block, off_times);
    b->resets = SLOT(block, off_resets);
    if (b->segments == NULL || b->episodes == NULL || b->times == NULL || pending == NULL ||
        b->resets == NULL || !PyList_CheckExact(b->segments) ||
        !PyDict_CheckExact(b->episodes) || !Py_IS_TYPE(b->times, array_type) ||
        !PyLong_CheckExact(pending) || !PyList_CheckExact(b->resets))
        return 0;
    Py_ssize_t waiting = PyLong_AsSsize_t(pending), index = PyLong_AsSsize_t(b->next);
    if (waiting < 0 || index < 0 || index == PY_SSIZE_T_MAX)
        return 0; /* (an error an overflow set is the caller's to clear) */
    b->first_row = Py_SIZE(b->times) + waiting;
    return 1;
}

int begin_make(Beginning *b, PyObject *seed, PyObject *rng_json, long long start_ns)
{
    b->next_after = PyLong_FromSsize_t(PyLong_AsSsize_t(b->next) + 1); /* (begin_read: fits) */
    b->segment = b->next_after == NULL
                     ? NULL
                     : Py_BuildValue("(nOiO)", b->first_row, b->next, 0, Py_True);
    b->fresh = b->segment == NULL ? NULL
                                  : new_episode(b->next, seed, rng_json, start_ns, b->env_index,
                                                b->agent);
    if (b->fresh == NULL)
        return -1;
    untrack(b->fresh);
    untrack(b->segment);
    return 0;
}

int begin_apply(Beginning *b)
{
    /* The file's next index first: if that fails, nothing else has changed. */
    if (PyObject_SetAttr(b->file, s_next_episode, b->next_after) < 0 ||
        PyObject_SetAttr(b->stream, s_episode, b->fresh) < 0 ||
        PyList_Append(b->segments, b->segment) < 0 ||
        PyDict_SetItem(b->episodes, b->next, b->fresh) < 0)
        return -1;
    return 0;
}

void begin_clear(Beginning *b)
{
    Py_CLEAR(b->episode);
    Py_CLEAR(b->block);
    Py_CLEAR(b->next);
    Py_CLEAR(b->env_index);
    Py_CLEAR(b->agent);
    Py_CLEAR(b->next_after);
    Py_CLEAR(b->segment);
    Py_CLEAR(b->fresh);
}

static PyObject *StepRecorder_begin(StepRecorder *self, PyObject *seed)
{
    Beginning b = {.file = self->file, .stream = self->stream};
    PyObject *ret = NULL;
    long long number, now;
    int overflow = 0, got;
    if (!PyLong_CheckExact(seed))
        Py_RETURN_NONE;
    number = PyLong_AsLongLongAndOverflow(seed, &overflow);
    if (overflow || number < 0) { /* (-1 with an error cannot happen for an exact int) */
        PyErr_Clear();
        Py_RETURN_NONE;
    }
    b.episode = stream_attr(self, S_EPISODE);
    b.block = b.episode == NULL ? NULL : stream_attr(self, S_BLOCK);
    got = b.block == NULL ? -1 : begin_read(&b);
    if (got == 0)
        goto decline;
    if (got < 0 || read_file_clock(self, &now) < 0 || begin_make(&b, seed, Py_None, now) < 0 ||
        begin_apply(&b) < 0)
        goto done;
    ret = Py_NewRef(b.fresh);
    goto done;
decline:
    PyErr_Clear();
    ret = Py_NewRef(Py_None);
done:
    begin_clear(&b);
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
    row = PyTuple_Pack(8, SLOT(episode, off_ep[E_INDEX]), SLOT(episode, off_ep[E_START_NS]),
                       SLOT(episode, off_ep[E_SEED]), Py_None,
                       SLOT(episode, off_ep[E_OPTIONS_JSON]), SLOT(episode, off_ep[E_GAME]),
                       Py_None, SLOT(episode, off_ep[E_OPTIONS_TYPED]));
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

PyTypeObject StepRecorderType = {
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
