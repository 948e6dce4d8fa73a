/* The recorder's per-step path, compiled: episode_audit.record._stepfast. This file holds the
   state the others share (set by configure()) and the module; stepfast.h lists the files.

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
   Modules/arraymodule.c, the same in 3.10-3.14) is declared in stepfast.h and checked when
   configure() runs (layout_ok); a layout that does not match leaves the module unusable, and the
   recorder takes the Python path. The arrays written here hold 8-byte items ('d', 'q'). */

#define STEPFAST_IMPORTS_ARRAY
#include "stepfast.h"

/* Set by configure(): the classes, and their slots' offsets. */
PyTypeObject *array_type, *block_type, *episode_type, *flat_type, *nd_type, *int_type;
PyObject *monotonic_ns;
Py_ssize_t off_ends, off_flags, off_segments, off_episodes, off_pending,
    off_reset_obs, off_resets;
/* Episode's slots, all of them: begin() makes an Episode as its __init__ would (EPISODE_SLOTS
   must name every slot the class has: configure() checks). */
static const char *episode_slots[EPISODE_SLOTS] = {
    "after_end", "agent", "end_ns", "ended", "env_index", "game", "index", "notes", "options",
    "options_json", "options_typed", "ret", "rng_json", "seed", "start_ns", "steps", "totals"};
Py_ssize_t off_ep[EPISODE_SLOTS];
Py_ssize_t off_obs, off_act, off_rewards, off_times, off_term_vals, off_term_rows,
    off_term_counts, off_term_keys;
Py_ssize_t off_arr_data, off_arr_n, off_arr_dtype, off_int_data, off_int_n;
int configured;

PyObject *s_episode, *s_block, *s_terms_keys, *s_terms_names, *s_block_steps, *s_file,
    *s_flush_at, *s_end_by_flags, *s_auto_flush, *s_step, *s_clock, *s_flag_endings,
    *s_ending_keys, *s_limit_hit, *s_pending, *s_counts, *s_episodes, *s_outcome,
    *s_failure_label, *s_truncation_reason, *s_terminated, *s_truncated, *s_error,
    *s_time_limit, *s_elapsed_steps, *s_max_episode_steps, *s_next_episode, *s_env_index,
    *s_agent, *s_slots, *s_file_clock, *s_error_ns, *s_busy, *s_gated, *s_env, *s_on_error;


/* Take `op` out of the cyclic garbage collector's lists, as CPython does itself with a tuple
   or dict that holds no tracked object. Only for the objects a recorder makes per episode (its
   Episode, ending pair, row tuples: native.untrack says which), which hold ints, texts, bools,
   None, JSON data of their own and each other: no reference cycle can pass through them, so
   the collector need not scan them. Otherwise each one is scanned at every young collection
   it lives through, and the episodes waiting for a flush are promoted to the oldest
   generation, whose growth sets off full collections of the whole process. */
void untrack(PyObject *op)
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
Py_ssize_t member_offset(PyTypeObject *type, PyObject *name)
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
int array_room(PyObject *a, Py_ssize_t count, Py_ssize_t itemsize)
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
    {"count_rows", count_rows, METH_VARARGS,
     "count_rows(block, n): (episode column, step column, names), or None (not taken)"},
    {"repeated_text", repeated_text, METH_VARARGS,
     "repeated_text(names, times): (int32 offsets, UTF-8 data) of the names repeated, or None"},
    {"sparse_text", sparse_text, METH_VARARGS,
     "sparse_text(n, {row: text}): (validity, int32 offsets, UTF-8 data, null count), or None"},
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
    INTERN(s_busy, "_busy");
    INTERN(s_gated, "_gated");
    INTERN(s_env, "env");
    INTERN(s_on_error, "_on_error");
    PyObject *time = PyImport_ImportModule("time");
    if (time == NULL)
        return NULL;
    monotonic_ns = PyObject_GetAttrString(time, "monotonic_ns");
    Py_DECREF(time);
    if (monotonic_ns == NULL || PyType_Ready(&StepRecorderType) < 0 ||
        PyType_Ready(&WrapperStepType) < 0)
        return NULL;
    PyObject *module = PyModule_Create(&module_def);
    if (module == NULL)
        return NULL;
    if (PyModule_AddObjectRef(module, "StepRecorder", (PyObject *)&StepRecorderType) < 0 ||
        PyModule_AddObjectRef(module, "WrapperStep", (PyObject *)&WrapperStepType) < 0) {
        Py_DECREF(module);
        return NULL;
    }
    return module;
}
