/* RecordEvidence's step, compiled: WrapperStep (installed by RecordEvidence as its `step`).

   WrapperStep(recorder, record, python_step) is called as recorder.step(action) is, and does
   what RecordEvidence.step does, without a Python frame: `_busy` read and set, the gate read,
   the wrapped env's step called, the step recorded by `record` (the recorder's StepRecorder),
   `_busy` cleared as it returns or raises. The env's own exception (an Exception) ends the open
   episode as RecordEvidence.step does, by the recorder's `_on_error(exc, "step", action)`, and is
   raised as it came. Any other call (gated: closed, or a flush() / close() under way in
   another thread; keyword or extra arguments; an instance without its attributes) goes to
   `python_step` (RecordEvidence.step) untouched.

   `thread` is the thread inside a call made here, for RecordEvidence._busy_here: FileRecorder's
   protocol reads the stack to tell its own thread's call from another's, and this call has no
   Python frame. */

#include "stepfast.h"
#include "pythread.h"

typedef struct {
    PyObject_HEAD
    PyObject *recorder;    /* (its dict holds this: a cycle, as its file's owner is) */
    PyObject *record;      /* the recorder's StepRecorder: record(action, result) */
    PyObject *python_step; /* RecordEvidence.step: python_step(recorder, *args, **kwargs) */
    unsigned long thread;  /* the thread inside a call made here; 0: none */
    vectorcallfunc vectorcall;
    PyTypeObject *type;    /* the recorder's class when the flags below are its slots */
    Py_ssize_t off_busy, off_gated; /* the offsets of its `_busy` and `_gated` slots */
} WrapperStep;

/* The recorder's flag `name` (`_busy`, `_gated`), borrowed: from its slot (at `offset`) when
   `slots`, else from its dict; NULL when unset or on an error. */
static inline PyObject *flag(PyObject *recorder, PyObject *dict, int slots, Py_ssize_t offset,
                             PyObject *name)
{
    return slots ? SLOT(recorder, offset) : PyDict_GetItemWithError(dict, name);
}

/* Set the recorder's flag `name` to `value` (as flag() reads it): 0, or -1 on an error. */
static inline int set_flag(PyObject *recorder, PyObject *dict, int slots, Py_ssize_t offset,
                           PyObject *name, PyObject *value)
{
    if (!slots)
        return PyDict_SetItem(dict, name, value);
    Py_XSETREF(SLOT(recorder, offset), Py_NewRef(value));
    return 0;
}

static PyObject *python_path(WrapperStep *self, PyObject *recorder, PyObject *const *args,
                             size_t nargsf, PyObject *kwnames)
{
    PyObject *bound = PyMethod_New(self->python_step, recorder);
    if (bound == NULL)
        return NULL;
    PyObject *result = PyObject_Vectorcall(bound, args, nargsf, kwnames);
    Py_DECREF(bound);
    return result;
}

/* The env raised (an error is set) on `action`: when it is an Exception,
   recorder._on_error(exc, "step", action) as RecordEvidence.step's `except Exception` does; the env's exception stays set (or what
   _on_error raised, with the env's as its context). */
static void env_raised(PyObject *recorder, PyObject *action)
{
    if (!PyErr_ExceptionMatches(PyExc_Exception))
        return;
    PyObject *type, *value, *traceback;
    PyErr_Fetch(&type, &value, &traceback);
    PyErr_NormalizeException(&type, &value, &traceback);
    if (traceback != NULL)
        PyException_SetTraceback(value, traceback);
    PyObject *done = PyObject_CallMethodObjArgs(recorder, s_on_error, value, s_step, action, NULL);
    if (done != NULL) {
        Py_DECREF(done);
        PyErr_Restore(type, value, traceback);
        return;
    }
    PyObject *type2, *value2, *traceback2;
    PyErr_Fetch(&type2, &value2, &traceback2);
    PyErr_NormalizeException(&type2, &value2, &traceback2);
    PyException_SetContext(value2, value); /* (steals value) */
    Py_DECREF(type);
    Py_XDECREF(traceback);
    PyErr_Restore(type2, value2, traceback2);
}

static PyObject *WrapperStep_vectorcall(PyObject *callable, PyObject *const *args, size_t nargsf,
                                        PyObject *kwnames)
{
    WrapperStep *self = (WrapperStep *)callable;
    PyObject *recorder = Py_NewRef(self->recorder);
    PyObject *ret = NULL, *dict = NULL, *env = NULL;
    if (PyVectorcall_NARGS(nargsf) != 1 || kwnames != NULL)
        goto python;
    dict = PyObject_GenericGetDict(recorder, NULL);
    if (dict == NULL || !PyDict_CheckExact(dict))
        goto python;
    /* (RecordEvidence's flags are slots: a pointer each, where a dict costs ~0.2 k
       instructions an access) */
    int slots = Py_TYPE(recorder) == self->type;
    /* as RecordEvidence.step: `_busy` first (a call under way: the Python path refuses
       another thread's), then the gate */
    if (flag(recorder, dict, slots, self->off_busy, s_busy) != Py_False)
        goto python;
    if (set_flag(recorder, dict, slots, self->off_busy, s_busy, Py_True) < 0)
        goto python;
    if (flag(recorder, dict, slots, self->off_gated, s_gated) != Py_False) {
        /* (gated, or no gate yet: the Python path decides, setting `_busy` itself) */
        if (set_flag(recorder, dict, slots, self->off_busy, s_busy, Py_False) < 0)
            PyErr_Clear();
        goto python;
    }
    env = PyDict_GetItemWithError(dict, s_env);
    if (env == NULL)
        goto python;
    Py_INCREF(env);
    unsigned long outer = self->thread;
    self->thread = PyThread_get_thread_ident();
    PyObject *env_args[2] = {env, args[0]};
    ret = PyObject_VectorcallMethod(s_step, env_args, 2, NULL);
    if (ret == NULL) {
        env_raised(recorder, args[0]);
    } else {
        PyObject *record_args[2] = {args[0], ret};
        PyObject *recorded = PyObject_Vectorcall(self->record, record_args, 2, NULL);
        if (recorded == NULL)
            Py_CLEAR(ret);
        else
            Py_DECREF(recorded);
    }
    self->thread = outer;
    /* `_busy` cleared as the call returns or raises (an error kept as it is) */
    PyObject *type, *value, *traceback;
    PyErr_Fetch(&type, &value, &traceback);
    if (set_flag(recorder, dict, slots, self->off_busy, s_busy, Py_False) < 0) {
        if (type != NULL) { /* (the call's own error wins) */
            PyErr_Clear();
            PyErr_Restore(type, value, traceback);
        } else {
            Py_CLEAR(ret);
        }
    } else {
        PyErr_Restore(type, value, traceback);
    }
    Py_DECREF(env);
    Py_DECREF(dict);
    Py_DECREF(recorder);
    return ret;
python:
    if (PyErr_Occurred()) {
        if (!PyErr_ExceptionMatches(PyExc_Exception)) { /* (a KeyboardInterrupt: raised) */
            Py_XDECREF(dict);
            Py_DECREF(recorder);
            return NULL;
        }
        PyErr_Clear();
    }
    Py_XDECREF(dict);
    ret = python_path(self, recorder, args, nargsf, kwnames);
    Py_DECREF(recorder);
    return ret;
}

static PyObject *WrapperStep_new(PyTypeObject *type, PyObject *args, PyObject *kwargs)
{
    PyObject *recorder, *record, *python_step;
    static char *kw[] = {"recorder", "record", "python_step", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "OOO:WrapperStep", kw, &recorder, &record,
                                     &python_step))
        return NULL;
    if (!PyCallable_Check(record) || !PyCallable_Check(python_step)) {
        PyErr_SetString(PyExc_TypeError, "WrapperStep: record and python_step must be callable");
        return NULL;
    }
    WrapperStep *self = (WrapperStep *)type->tp_alloc(type, 0);
    if (self == NULL)
        return NULL;
    self->vectorcall = WrapperStep_vectorcall;
    self->recorder = Py_NewRef(recorder);
    self->record = Py_NewRef(record);
    self->python_step = Py_NewRef(python_step);
    self->off_busy = member_offset(Py_TYPE(recorder), s_busy);
    self->off_gated = member_offset(Py_TYPE(recorder), s_gated);
    if (PyErr_Occurred()) {
        Py_DECREF(self);
        return NULL;
    }
    /* (its class, kept only while both flags are its slots: no reference, the recorder's) */
    self->type = self->off_busy >= 0 && self->off_gated >= 0 ? Py_TYPE(recorder) : NULL;
    return (PyObject *)self;
}

static PyObject *WrapperStep_inside_here(WrapperStep *self, PyObject *unused)
{
    return PyBool_FromLong(self->thread != 0 && self->thread == PyThread_get_thread_ident());
}

static PyObject *WrapperStep_call(PyObject *self, PyObject *args, PyObject *kwargs)
{
    return PyVectorcall_Call(self, args, kwargs);
}

static int WrapperStep_traverse(WrapperStep *self, visitproc visit, void *arg)
{
    Py_VISIT(self->recorder);
    Py_VISIT(self->record);
    Py_VISIT(self->python_step);
    return 0;
}

static int WrapperStep_clear(WrapperStep *self)
{
    Py_CLEAR(self->recorder);
    Py_CLEAR(self->record);
    Py_CLEAR(self->python_step);
    return 0;
}

static void WrapperStep_dealloc(WrapperStep *self)
{
    PyObject_GC_UnTrack(self);
    WrapperStep_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyMethodDef WrapperStep_methods[] = {
    {"inside_here", (PyCFunction)WrapperStep_inside_here, METH_NOARGS,
     "inside_here(): whether this thread is inside a call made here (for _busy_here)."},
    {NULL}};

static PyMemberDef WrapperStep_members[] = {
    {"record", T_OBJECT_EX, offsetof(WrapperStep, record), READONLY,
     "The recorder's StepRecorder."},
    {NULL}};

PyTypeObject WrapperStepType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "episode_audit.record._stepfast.WrapperStep",
    .tp_basicsize = sizeof(WrapperStep),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC | Py_TPFLAGS_HAVE_VECTORCALL,
    .tp_doc = "WrapperStep(recorder, record, python_step): RecordEvidence.step, compiled: "
              "step(action) -> (obs, reward, terminated, truncated, info).",
    .tp_new = WrapperStep_new,
    .tp_traverse = (traverseproc)WrapperStep_traverse,
    .tp_clear = (inquiry)WrapperStep_clear,
    .tp_dealloc = (destructor)WrapperStep_dealloc,
    .tp_call = WrapperStep_call,
    .tp_vectorcall_offset = offsetof(WrapperStep, vectorcall),
    .tp_members = WrapperStep_members,
    .tp_methods = WrapperStep_methods,
};
