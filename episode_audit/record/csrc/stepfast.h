/* What the files of episode_audit.record._stepfast share (module.c says what it is).

   The extension is one module built from these files: module.c (the shared state, configure,
   the module), step.c (the single-env step and reset: StepRecorder), wrapper.c
   (RecordEvidence's step: WrapperStep), records.c (episode records,
   RNG states, message framing), blocks.c (a block's rows counted into their episodes, its
   columns of text) and vector.c (the vector recorder's steps). Only PyInit__stepfast
   is exported (setup.py builds with hidden visibility). */

#ifndef EPISODE_AUDIT_STEPFAST_H
#define EPISODE_AUDIT_STEPFAST_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <string.h>
#include <time.h>

/* numpy's C API table: filled by module.c's import_array(), read by every file */
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#define PY_ARRAY_UNIQUE_SYMBOL episode_audit_stepfast_ARRAY_API
#ifndef STEPFAST_IMPORTS_ARRAY
#define NO_IMPORT_ARRAY
#endif
#include <numpy/arrayobject.h>
#include <numpy/arrayscalars.h>

#define MAX_TERMS 64

/* array.array's object layout (CPython's Modules/arraymodule.c, the same in 3.10-3.14),
   checked when configure() runs (module.c, layout_ok). */
typedef struct {
    PyObject_VAR_HEAD
    char *ob_item;
    Py_ssize_t allocated;
    const void *ob_descr;
    PyObject *weakreflist;
    Py_ssize_t ob_exports;
} ArrayObject;

/* Set by configure() (module.c): the classes, and their slots' offsets. */
extern PyTypeObject *array_type, *block_type, *episode_type, *flat_type, *nd_type, *int_type;
extern PyObject *monotonic_ns;
extern Py_ssize_t off_ends, off_flags, off_segments, off_episodes, off_pending, off_reset_obs,
    off_resets;
/* Episode's slots, all of them (module.c's episode_slots names them in this order). */
#define EPISODE_SLOTS 17
enum { E_AFTER_END, E_AGENT, E_END_NS, E_ENDED, E_ENV_INDEX, E_GAME, E_INDEX, E_NOTES, E_OPTIONS,
       E_OPTIONS_JSON, E_OPTIONS_TYPED, E_RET, E_RNG_JSON, E_SEED, E_START_NS, E_STEPS,
       E_TOTALS };
extern Py_ssize_t off_ep[EPISODE_SLOTS];
extern Py_ssize_t off_obs, off_act, off_rewards, off_times, off_term_vals, off_term_rows,
    off_term_counts, off_term_keys;
extern Py_ssize_t off_arr_data, off_arr_n, off_arr_dtype, off_int_data, off_int_n;
extern int configured;

/* Attribute names, interned when the module loads. */
extern PyObject *s_episode, *s_block, *s_terms_keys, *s_terms_names, *s_block_steps, *s_file,
    *s_flush_at, *s_end_by_flags, *s_auto_flush, *s_step, *s_clock, *s_flag_endings,
    *s_ending_keys, *s_limit_hit, *s_pending, *s_counts, *s_episodes, *s_outcome,
    *s_failure_label, *s_truncation_reason, *s_terminated, *s_truncated, *s_error,
    *s_time_limit, *s_elapsed_steps, *s_max_episode_steps, *s_next_episode, *s_env_index,
    *s_agent, *s_slots, *s_file_clock, *s_error_ns, *s_busy, *s_gated, *s_env, *s_on_error;

#define SLOT(obj, off) (*(PyObject **)((char *)(obj) + (off)))

/* module.c */
void untrack(PyObject *op);
Py_ssize_t member_offset(PyTypeObject *type, PyObject *name);
int array_room(PyObject *a, Py_ssize_t count, Py_ssize_t itemsize);

static inline void array_push_d(PyObject *a, double value)
{
    ArrayObject *arr = (ArrayObject *)a;
    ((double *)arr->ob_item)[Py_SIZE(arr)] = value;
    Py_SET_SIZE(arr, Py_SIZE(arr) + 1);
}

/* A float, an int or a numpy number (or bool) scalar: what float() reads as it is. Anything
   else (an array, a tensor, text) goes to the Python path, where number() decides. */
static inline int plain_number(PyObject *x)
{
    return PyFloat_Check(x) || PyLong_Check(x) || PyArray_IsScalar(x, Number) ||
           PyArray_IsScalar(x, Bool);
}

/* `x` as float() reads it, into *out: 1; 0 when it is not a plain number (the Python path
   decides); -1 on an error (set). A float, a numpy float64 (a float subclass with float's
   layout) or float32 (what float() gives: its value, exactly) is read in place: no call, no
   walk of its type's bases. */
static inline int number_value(PyObject *x, double *out)
{
    PyTypeObject *type = Py_TYPE(x);
    if (type == &PyFloat_Type || type == &PyDoubleArrType_Type) {
        *out = PyFloat_AS_DOUBLE(x);
        return 1;
    }
    if (type == &PyFloatArrType_Type) {
        *out = (double)PyArrayScalar_VAL(x, Float);
        return 1;
    }
    if (!plain_number(x))
        return 0;
    double value = PyFloat_AsDouble(x);
    if (value == -1.0 && PyErr_Occurred())
        return -1;
    *out = value;
    return 1;
}

static inline void array_push_q(PyObject *a, long long value)
{
    ArrayObject *arr = (ArrayObject *)a;
    ((long long *)arr->ob_item)[Py_SIZE(arr)] = value;
    Py_SET_SIZE(arr, Py_SIZE(arr) + 1);
}

/* step.c: column buffers, the single-env step and reset */

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

int plan_value(PyObject *buffer, PyObject *value, Pending *p);
void commit_value(Pending *p);
int as_long_long(PyObject *value, long long *out);
int call_clock(PyObject *clock, long long *now);
int end_by_flags(PyObject *stream, PyObject *episode, PyObject *block, Py_ssize_t row,
                 PyObject *terminated, PyObject *truncated, PyObject *info);
PyObject *new_episode(PyObject *index, PyObject *seed, PyObject *rng_json, long long start_ns,
                      PyObject *env_index, PyObject *agent);
extern PyTypeObject StepRecorderType;
extern PyTypeObject WrapperStepType; /* wrapper.c */

/* Beginning a stream's next episode, as EpisodeStream.begin does (the single-env reset and the
   vector recorder's autoreset): the caller sets file, stream, episode and block (those two new
   references), then begin_read reads the rest and checks it (1; 0: declined, an error perhaps
   set for the caller to clear; -1: an error), begin_make makes the episode and its segment
   without changing anything (0, or -1), begin_apply begins it (0, or -1). begin_clear drops
   the references, whatever the step reached. */
typedef struct {
    PyObject *file, *stream;                              /* borrowed */
    PyObject *episode, *block, *next, *env_index, *agent; /* new references, read */
    PyObject *segments, *episodes, *times, *resets;       /* the block's, borrowed */
    Py_ssize_t first_row;                                 /* the episode's first row */
    PyObject *next_after, *segment, *fresh;               /* new references, made */
} Beginning;

int begin_read(Beginning *b);
int begin_make(Beginning *b, PyObject *seed, PyObject *rng_json, long long start_ns);
int begin_apply(Beginning *b);
void begin_clear(Beginning *b);

/* records.c: episode records, RNG states, message framing */
PyObject *episode_json(PyObject *module, PyObject *args);
PyObject *episode_columns(PyObject *module, PyObject *args);
PyObject *rng_json(PyObject *module, PyObject *args);
PyObject *frame_messages(PyObject *module, PyObject *args);

/* blocks.c: a block's rows counted into their episodes, and its columns of text */
PyObject *count_rows(PyObject *module, PyObject *args);
PyObject *repeated_text(PyObject *module, PyObject *args);
PyObject *sparse_text(PyObject *module, PyObject *args);

/* vector.c: the vector recorder's steps */
PyObject *vector_step(PyObject *module, PyObject *const *args, Py_ssize_t nargs);
PyObject *end_batched(PyObject *module, PyObject *const *args, Py_ssize_t nargs);
PyObject *begin_autoreset(PyObject *module, PyObject *const *args, Py_ssize_t nargs);

#endif
