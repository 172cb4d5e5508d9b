/* The per-frame and per-message hot path in C (issue 31): a CPython extension on the stable ABI (3.11), over the
 * C runtime's own framing and header code (firmware/src/can.c, wire.c), so the two cannot disagree.
 *
 * - decode(raw) -> Message | None: asm_py.protocol.decode for a node's receive path (None: not a valid message;
 *   the caller asks the Python decoder for the reason).
 * - Receiver(transport): called with every received python-can frame, it does what CanTransport.on_frame and
 *   on_message do for the common frames — checks, counting, the identifier, acceptance, the source's liveness
 *   and name — and hands a single-frame message to transport._deliver (or to an overriding on_message); 0 if the
 *   frame is not an ASM frame, 1 when it handled it, 2 when it counted it and Python must go on (the logger,
 *   e-stops, system frames, groups and broadcasts, fragments, publications, a peer heard for the first time).
 *
 * asm_py/speedups.py loads this module, or says why not and leaves the pure-Python path (the same tests run over
 * both: tests/transport/test_transport_conformance.py).
 */
#define Py_LIMITED_API 0x030B0000
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <time.h>

#include "asm/can.h"
#include "asm/wire.h"

/* -- decode ------------------------------------------------------------------------------------------------------ */

typedef struct {
    PyObject *message_type; /* asm_py.protocol.Message (a tuple subclass) */
    PyObject *tuple_new;    /* tuple.__new__ */
    PyObject *small[256];   /* the ints 0..255, held (header fields) */
    PyObject *status_ok;    /* Status.OK: a request's status, as the Python decoder gives it */
} State;

static State *state_of(PyObject *module) { return (State *)PyModule_GetState(module); }

static PyObject *make_message(State *st, const struct asm_message *m)
{
    PyObject *data = PyBytes_FromStringAndSize((const char *)m->data, (Py_ssize_t)m->length);
    if (data == NULL)
        return NULL;
    PyObject *timeout = m->timeout < 0 ? Py_None : st->small[m->timeout];
    PyObject *status = m->kind == ASM_REPLY ? st->small[m->status] : st->status_ok;
    PyObject *items = PyTuple_Pack(8, st->small[m->kind], st->small[m->method], st->small[m->txn],
                                   st->small[m->class_id], st->small[m->object_id], status, timeout, data);
    Py_DECREF(data);
    if (items == NULL)
        return NULL;
    PyObject *message = PyObject_CallFunctionObjArgs(st->tuple_new, st->message_type, items, NULL);
    Py_DECREF(items);
    return message;
}

static PyObject *speedups_decode(PyObject *module, PyObject *raw)
{
    State *st = state_of(module);
    if (st->message_type == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "asm_py._speedups.setup() was not called");
        return NULL;
    }
    char *bytes;
    Py_ssize_t length;
    if (!PyBytes_Check(raw) || PyBytes_AsStringAndSize(raw, &bytes, &length) < 0) {
        PyErr_Clear();
        Py_RETURN_NONE; /* not bytes: the Python decoder takes it */
    }
    struct asm_message m;
    if (asm_decode((const uint8_t *)bytes, (size_t)length, &m) != ASM_OK)
        Py_RETURN_NONE;
    return make_message(st, &m);
}

static PyObject *speedups_setup(PyObject *module, PyObject *args)
{
    State *st = state_of(module);
    PyObject *message_type, *status_ok;
    if (!PyArg_ParseTuple(args, "OO", &message_type, &status_ok))
        return NULL;
    Py_INCREF(status_ok);
    Py_XDECREF(st->status_ok);
    st->status_ok = status_ok;
    PyObject *tuple_new = PyObject_GetAttrString((PyObject *)&PyTuple_Type, "__new__");
    if (tuple_new == NULL)
        return NULL;
    Py_XDECREF(st->tuple_new);
    st->tuple_new = tuple_new;
    Py_INCREF(message_type);
    Py_XDECREF(st->message_type);
    st->message_type = message_type;
    Py_RETURN_NONE;
}

/* -- Receiver ---------------------------------------------------------------------------------------------------- */

typedef struct {
    PyObject_HEAD
    PyObject *transport;
    PyObject *accept_ids; /* the transport's sets and dicts, shared (mutated in place by Python) */
    PyObject *names;
    PyObject *last_heard;
    PyObject *alive;
    PyObject *deliver;    /* transport._deliver, or transport.on_message when a subclass overrides it */
    int overridden;       /* deliver is on_message(source_id, dest_kind, dest, data) */
    long node_id;
} Receiver;

static PyObject *s_is_extended_id, *s_is_error_frame, *s_is_remote_frame, *s_arbitration_id, *s_data,
    *s_frames_received, *s_logger;

static int truth(PyObject *frame, PyObject *name)
{
    PyObject *value = PyObject_GetAttr(frame, name);
    if (value == NULL)
        return -1;
    int result = PyObject_IsTrue(value);
    Py_DECREF(value);
    return result;
}

static int count_frame(PyObject *transport)
{
    PyObject *count = PyObject_GetAttr(transport, s_frames_received);
    if (count == NULL)
        return -1;
    PyObject *one = PyLong_FromLong(1);
    PyObject *more = one == NULL ? NULL : PyNumber_Add(count, one);
    Py_DECREF(count);
    Py_XDECREF(one);
    if (more == NULL)
        return -1;
    int result = PyObject_SetAttr(transport, s_frames_received, more);
    Py_DECREF(more);
    return result;
}

enum { IGNORED = 0, HANDLED = 1, GO_ON = 2 };

static PyObject *result(long code) { return PyLong_FromLong(code); }

static PyObject *receiver_call(PyObject *self_obj, PyObject *args, PyObject *kwargs)
{
    Receiver *self = (Receiver *)self_obj;
    PyObject *frame;
    (void)kwargs;
    if (!PyArg_ParseTuple(args, "O", &frame))
        return NULL;
    int extended = truth(frame, s_is_extended_id);
    if (extended < 0)
        return NULL;
    int error = extended ? truth(frame, s_is_error_frame) : 1;
    if (error < 0)
        return NULL;
    int remote = error ? 1 : truth(frame, s_is_remote_frame);
    if (remote < 0)
        return NULL;
    if (!extended || error || remote)
        return result(IGNORED);
    if (count_frame(self->transport) < 0)
        return NULL;
    PyObject *logger = PyObject_GetAttr(self->transport, s_logger);
    if (logger == NULL)
        return NULL;
    int logging = logger != Py_None;
    Py_DECREF(logger);
    PyObject *ident_obj = PyObject_GetAttr(frame, s_arbitration_id);
    if (ident_obj == NULL)
        return NULL;
    unsigned long ident = PyLong_AsUnsignedLongMask(ident_obj);
    Py_DECREF(ident_obj);
    if (PyErr_Occurred())
        return NULL;
    struct asm_can_id id;
    asm_can_unpack((uint32_t)ident, &id);
    if (logging || id.dest_kind != ASM_DEST_NODE)
        return result(GO_ON); /* the logger, e-stops and system frames, groups and broadcasts: Python */
    if (id.source == self->node_id || id.source < 1 || id.source > 254)
        return result(HANDLED); /* our own frame (a loopback interface), or a forged source: dropped */
    State *st = (State *)PyType_GetModuleState(Py_TYPE(self_obj));
    int accepted = PySet_Contains(self->accept_ids, st->small[id.dest]);
    if (accepted <= 0)
        return accepted < 0 ? NULL : result(HANDLED);
    if (id.frame != ASM_SINGLE)
        return result(GO_ON); /* a fragment: the reassembler */
    PyObject *source_id = st->small[id.source];
    int alive = PySet_Contains(self->alive, source_id);
    if (alive < 0)
        return NULL;
    if (!alive)
        return result(GO_ON); /* perhaps a peer heard for the first time: Python says so */
    PyObject *data_obj = PyObject_GetAttr(frame, s_data);
    if (data_obj == NULL)
        return NULL;
    PyObject *data = PyBytes_FromObject(data_obj);
    Py_DECREF(data_obj);
    if (data == NULL)
        return NULL;
    char *bytes = PyBytes_AsString(data);
    Py_ssize_t length = PyBytes_Size(data);
    if (length >= 4 && asm_kind_of((uint8_t)bytes[0]) == ASM_PUBLICATION) {
        Py_DECREF(data);
        return result(GO_ON); /* subscribers: Python */
    }
    PyObject *outcome;
    if (self->overridden) {
        outcome = PyObject_CallFunction(self->deliver, "OiiO", source_id, (int)id.dest_kind, (int)id.dest, data);
    } else {
        struct timespec now;
        clock_gettime(CLOCK_MONOTONIC, &now); /* time.monotonic()'s clock */
        PyObject *heard = PyFloat_FromDouble((double)now.tv_sec + (double)now.tv_nsec * 1e-9);
        if (heard == NULL || PyDict_SetItem(self->last_heard, source_id, heard) < 0) {
            Py_XDECREF(heard);
            Py_DECREF(data);
            return NULL;
        }
        Py_DECREF(heard);
        PyObject *name = PyDict_GetItemWithError(self->names, source_id); /* borrowed */
        if (name == NULL && PyErr_Occurred()) {
            Py_DECREF(data);
            return NULL;
        }
        if (name == NULL || PyUnicode_GetLength(name) == 0) { /* name_of: an empty name is no name */
            outcome = NULL;
            PyObject *alias = PyUnicode_FromFormat("can.%d", (int)id.source);
            if (alias != NULL) {
                outcome = PyObject_CallFunctionObjArgs(self->deliver, alias, data, NULL);
                Py_DECREF(alias);
            }
        } else {
            outcome = PyObject_CallFunctionObjArgs(self->deliver, name, data, NULL);
        }
    }
    Py_DECREF(data);
    if (outcome == NULL)
        return NULL;
    Py_DECREF(outcome);
    return result(HANDLED);
}

static PyObject *receiver_new(PyTypeObject *type, PyObject *args, PyObject *kwargs)
{
    PyObject *transport, *accept_ids, *names, *last_heard, *alive, *deliver;
    long node_id;
    int overridden;
    (void)kwargs;
    if (!PyArg_ParseTuple(args, "OlOOOOOp", &transport, &node_id, &accept_ids, &names, &last_heard, &alive, &deliver,
                          &overridden))
        return NULL;
    if (!PyAnySet_Check(accept_ids) || !PyAnySet_Check(alive) || !PyDict_Check(names) || !PyDict_Check(last_heard)) {
        PyErr_SetString(PyExc_TypeError, "Receiver needs the transport's sets and dicts");
        return NULL;
    }
    allocfunc alloc = (allocfunc)PyType_GetSlot(type, Py_tp_alloc);
    Receiver *self = (Receiver *)alloc(type, 0);
    if (self == NULL)
        return NULL;
    PyObject *held[] = {transport, accept_ids, names, last_heard, alive, deliver};
    for (size_t k = 0; k < sizeof held / sizeof held[0]; k++)
        Py_INCREF(held[k]);
    self->transport = transport;
    self->accept_ids = accept_ids;
    self->names = names;
    self->last_heard = last_heard;
    self->alive = alive;
    self->deliver = deliver;
    self->overridden = overridden;
    self->node_id = node_id;
    return (PyObject *)self;
}

static int receiver_traverse(PyObject *self_obj, visitproc visit, void *arg)
{
    Receiver *self = (Receiver *)self_obj;
    Py_VISIT(self->transport);
    Py_VISIT(self->accept_ids);
    Py_VISIT(self->names);
    Py_VISIT(self->last_heard);
    Py_VISIT(self->alive);
    Py_VISIT(self->deliver);
    Py_VISIT(Py_TYPE(self_obj));
    return 0;
}

static int receiver_clear(PyObject *self_obj)
{
    Receiver *self = (Receiver *)self_obj;
    Py_CLEAR(self->transport);
    Py_CLEAR(self->accept_ids);
    Py_CLEAR(self->names);
    Py_CLEAR(self->last_heard);
    Py_CLEAR(self->alive);
    Py_CLEAR(self->deliver);
    return 0;
}

static void receiver_dealloc(PyObject *self_obj)
{
    PyTypeObject *type = Py_TYPE(self_obj);
    PyObject_GC_UnTrack(self_obj);
    receiver_clear(self_obj);
    freefunc free_slot = (freefunc)PyType_GetSlot(type, Py_tp_free);
    free_slot(self_obj);
    Py_DECREF(type);
}

static PyType_Slot receiver_slots[] = {
    {Py_tp_new, receiver_new},
    {Py_tp_call, receiver_call},
    {Py_tp_traverse, receiver_traverse},
    {Py_tp_clear, receiver_clear},
    {Py_tp_dealloc, receiver_dealloc},
    {Py_tp_doc, "Receiver(transport, node_id, accept_ids, names, last_heard, alive, deliver, overridden)"},
    {0, NULL},
};

static PyType_Spec receiver_spec = {
    .name = "asm_py._speedups.Receiver",
    .basicsize = sizeof(Receiver),
    .flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .slots = receiver_slots,
};

/* -- the module -------------------------------------------------------------------------------------------------- */

static int speedups_exec(PyObject *module)
{
    State *st = state_of(module);
    for (int k = 0; k < 256; k++) {
        st->small[k] = PyLong_FromLong(k);
        if (st->small[k] == NULL)
            return -1;
    }
#define INTERN(var, text)                                                                                            \
    if ((var) == NULL && ((var) = PyUnicode_InternFromString(text)) == NULL)                                           \
        return -1;
    INTERN(s_is_extended_id, "is_extended_id")
    INTERN(s_is_error_frame, "is_error_frame")
    INTERN(s_is_remote_frame, "is_remote_frame")
    INTERN(s_arbitration_id, "arbitration_id")
    INTERN(s_data, "data")
    INTERN(s_frames_received, "frames_received")
    INTERN(s_logger, "_logger")
#undef INTERN
    PyObject *receiver = PyType_FromModuleAndSpec(module, &receiver_spec, NULL);
    if (receiver == NULL)
        return -1;
    int added = PyModule_AddObjectRef(module, "Receiver", receiver);
    Py_DECREF(receiver);
    return added;
}

static int speedups_traverse(PyObject *module, visitproc visit, void *arg)
{
    State *st = state_of(module);
    Py_VISIT(st->message_type);
    Py_VISIT(st->tuple_new);
    Py_VISIT(st->status_ok);
    return 0;
}

static int speedups_clear(PyObject *module)
{
    State *st = state_of(module);
    Py_CLEAR(st->message_type);
    Py_CLEAR(st->tuple_new);
    Py_CLEAR(st->status_ok);
    for (int k = 0; k < 256; k++)
        Py_CLEAR(st->small[k]);
    return 0;
}

static void speedups_free(void *module) { speedups_clear((PyObject *)module); }

static PyMethodDef speedups_methods[] = {
    {"decode", speedups_decode, METH_O, "decode(raw: bytes) -> Message | None"},
    {"setup", speedups_setup, METH_VARARGS, "setup(Message, Status.OK): the message type decode() makes"},
    {NULL, NULL, 0, NULL},
};

static PyModuleDef_Slot speedups_module_slots[] = {
    {Py_mod_exec, speedups_exec},
    {0, NULL},
};

static struct PyModuleDef speedups_module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "asm_py._speedups",
    .m_doc = "The per-frame and per-message hot path in C; see asm_py/speedups.py.",
    .m_size = sizeof(State),
    .m_methods = speedups_methods,
    .m_slots = speedups_module_slots,
    .m_traverse = speedups_traverse,
    .m_clear = speedups_clear,
    .m_free = speedups_free,
};

PyMODINIT_FUNC PyInit__speedups(void) { return PyModuleDef_Init(&speedups_module); }
