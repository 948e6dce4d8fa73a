#include "stepfast.h"

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

PyObject *vector_step(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
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
PyObject *end_batched(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
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


/* begin_autoreset(stream, rng_json, obs, start_ns): an autoreset of a vector recorder's
   sub-env, its info not kept, as NextStep.autoreset and SameStep._begin_next record it: the
   stream's next Episode (no seed, no options; `rng_json` the RNG state it reset from, as JSON
   bytes) begun at `start_ns`, and its reset row with the observation `obs`. True; or None when the
   stream has an open episode or `obs` does not go into the reset column as it is (nothing
   changed: the Python path records it). The stream keeps no info (the caller checks). */
PyObject *begin_autoreset(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "begin_autoreset: four arguments");
        return NULL;
    }
    PyObject *stream = args[0], *rng_json = args[1], *obs = args[2], *start = args[3];
    PyObject *file = NULL, *text = NULL, *row = NULL, *ret = NULL;
    Beginning b = {.stream = stream};
    Pending obs_p = {0};
    long long start_ns;
    int got;
    if (!PyBytes_CheckExact(rng_json) || !PyLong_CheckExact(start) ||
        as_long_long(start, &start_ns) < 0)
        goto decline;
    file = b.file = PyObject_GetAttr(stream, s_file);
    b.episode = file == NULL ? NULL : PyObject_GetAttr(stream, s_episode);
    b.block = b.episode == NULL ? NULL : PyObject_GetAttr(stream, s_block);
    got = b.block == NULL ? -1 : begin_read(&b);
    if (got < 0)
        goto done;
    if (got == 0 || !plan_value(SLOT(b.block, off_reset_obs), obs, &obs_p) ||
        obs_p.n != PyList_GET_SIZE(b.resets))
        goto decline;
    text = PyUnicode_DecodeUTF8(PyBytes_AS_STRING(rng_json), PyBytes_GET_SIZE(rng_json), NULL);
    if (text == NULL)
        goto decline;
    /* Everything made before anything changes. */
    if (begin_make(&b, Py_None, rng_json, start_ns) < 0)
        goto done;
    row = PyTuple_Pack(8, b.next, SLOT(b.fresh, off_ep[E_START_NS]), Py_None, text, Py_None,
                       Py_None, Py_None, Py_None);
    if (row == NULL)
        goto done;
    untrack(row);
    if (begin_apply(&b) < 0 || PyList_Append(b.resets, row) < 0)
        goto done;
    commit_value(&obs_p);
    ret = Py_NewRef(Py_True);
    goto done;
decline:
    PyErr_Clear();
    ret = Py_NewRef(Py_None);
done:
    Py_XDECREF(obs_p.count);
    begin_clear(&b);
    Py_XDECREF(file);
    Py_XDECREF(text);
    Py_XDECREF(row);
    return ret;
}
