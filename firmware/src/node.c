#include "asm/node.h"

#include "asm/codec.h"

#include <math.h>
#include <string.h>

#define HEARTBEAT_MS 500u

static int due(uint32_t now, uint32_t when) { return (int32_t)(now - when) >= 0; }

/* A loop, not strlen: newlib's word-at-a-time strlen is 220 bytes of a Cortex-M4's flash, for names of a few. */
static size_t length_of(const char *text)
{
    size_t n = 0;
    while (text[n])
        n++;
    return n;
}

/* -- sending ----------------------------------------------------------------------------------------------------- */

void asm_node_send(struct asm_node *n, uint8_t dest_kind, uint8_t dest, const uint8_t *msg, size_t length,
                   uint8_t priority)
{
    struct asm_fragmenter f;
    struct asm_can_id id = {0};
    uint8_t data[64], dlc;
    if (asm_fragment_begin(&f, msg, length, n->port.fd) != ASM_OK)
        return;
    id.priority = asm_frame_priority(priority, asm_fragment_count(length, n->port.fd));
    id.dest_kind = dest_kind;
    id.dest = dest;
    id.source = n->node_id;
    while (asm_fragment_next(&f, &id.frame, &id.counter, data, &dlc))
        if (n->port.send(n->port.ctx, asm_can_pack(&id), data, dlc) != 0)
            n->send_errors++;
}

static void heartbeat(struct asm_node *n)
{
    asm_node_send(n, ASM_DEST_SYSTEM, ASM_SYSTEM_HEARTBEAT, (const uint8_t *)n->name, length_of(n->name), ASM_PRIORITY_HEARTBEAT);
    n->next_heartbeat_ms = n->now_ms + n->heartbeat_ms;
}

/* A reply to ``source`` (header as in asm_py.server.reply): ``data`` may already sit in n->out + 4. */
static void reply(struct asm_node *n, uint8_t source, uint8_t method, uint8_t txn, uint8_t status, uint8_t object,
                  const void *data, size_t length)
{
    if (length > ASM_NODE_OUT - ASM_HEADER_SIZE) {
        status = ASM_S_TOO_LARGE;
        data = "reply too large for this module";
        length = length_of(data);
    }
    if (data != n->out + ASM_HEADER_SIZE && length)
        memcpy(n->out + ASM_HEADER_SIZE, data, length); /* never overlapping: not from n->out */
    n->out[0] = asm_first_byte(ASM_REPLY, method);
    n->out[1] = txn;
    n->out[2] = status;
    n->out[3] = object;
    asm_node_send(n, ASM_DEST_NODE, source, n->out, ASM_HEADER_SIZE + length, ASM_PRIORITY_REPLY);
}

static int is_float32(const struct asm_object *o)
{
    return o->descriptor_length == 1 && o->descriptor[0] == 0x0A && o->length == 4;
}

static void publish(struct asm_node *n, struct asm_object *o)
{
    struct asm_publication *p = &o->publication;
    if (o->length > ASM_NODE_OUT - ASM_HEADER_SIZE)
        return;
    n->out[0] = asm_first_byte(ASM_PUBLICATION, ASM_PUBLISH);
    n->out[1] = p->seq;
    n->out[2] = o->class_id;
    n->out[3] = o->id;
    memcpy(n->out + ASM_HEADER_SIZE, o->value, o->length);
    asm_node_send(n, ASM_DEST_BROADCAST, 0, n->out, ASM_HEADER_SIZE + o->length, ASM_PRIORITY_PUBLICATION);
    p->seq = (uint8_t)((p->seq + 1) & ASM_MAX_TXN);
    p->last_ms = n->now_ms;
    p->pending = 0;
    if (is_float32(o))
        memcpy(&p->last_value, o->value, 4);
}

static float as_float(const struct asm_object *o)
{
    float v = 0.0f;
    if (is_float32(o))
        memcpy(&v, o->value, 4);
    return v;
}

/* -- registration ------------------------------------------------------------------------------------------------ */

void asm_object_init(struct asm_object *o, const char *name, uint8_t class_id, uint8_t kind, const uint8_t *descriptor,
                     uint8_t descriptor_length, void *value, uint16_t length, uint16_t capacity)
{
    memset(o, 0, sizeof *o);
    o->name = name;
    o->class_id = class_id;
    o->kind = kind;
    o->descriptor = descriptor;
    o->descriptor_length = descriptor_length;
    o->value = value;
    o->length = length;
    o->capacity = capacity;
    o->valid = 1;
}

void asm_node_init(struct asm_node *n, const char *name, uint8_t node_id, const struct asm_port *port, uint32_t now_ms)
{
    memset(n, 0, sizeof *n);
    n->name = name;
    n->node_id = node_id;
    n->port = *port;
    n->now_ms = now_ms;
    n->heartbeat_ms = HEARTBEAT_MS;
    asm_reassembler_init(&n->rx);
    heartbeat(n);
}

/* A loop, not strcmp: newlib's word-at-a-time strcmp alone is 732 bytes of a Cortex-M4's flash. */
static int same_name(const char *a, const char *b)
{
    while (*a && *a == *b)
        a++, b++;
    return *a == *b;
}

struct asm_object *asm_node_find(struct asm_node *n, const char *name)
{
    for (uint8_t k = 0; k < n->count; k++)
        if (same_name(n->objects[k]->name, name))
            return n->objects[k];
    return NULL;
}

int asm_node_register(struct asm_node *n, struct asm_object *o)
{
    if (n->count >= ASM_MAX_OBJECTS)
        return ASM_E_TOO_LARGE;
    if (asm_node_find(n, o->name) != NULL || o->length > o->capacity)
        return ASM_E_RANGE;
    n->objects[n->count++] = o;
    o->id = n->count;
    o->publication.last_ms = n->now_ms;
    return ASM_OK;
}

int asm_node_join(struct asm_node *n, uint8_t group)
{
    for (uint8_t k = 0; k < n->group_count; k++)
        if (n->groups[k] == group)
            return ASM_OK;
    if (n->group_count >= ASM_MAX_GROUPS)
        return ASM_E_TOO_LARGE;
    n->groups[n->group_count++] = group;
    return ASM_OK;
}

/* -- values ------------------------------------------------------------------------------------------------------ */

static void answer_waits(struct asm_node *n, struct asm_object *o)
{
    for (unsigned k = 0; k < ASM_MAX_WAITS; k++) {
        struct asm_wait *w = &n->waits[k];
        if (!w->used || w->object != o)
            continue;
        if (w->method == ASM_GET) {
            if (!o->valid)
                continue; /* an earlier waiting GET consumed it */
            o->valid = 0;
        }
        w->used = 0;
        reply(n, w->source, w->method, w->txn, ASM_S_OK, w->object_byte, o->value, o->length);
    }
}

static void changed(struct asm_node *n, struct asm_object *o)
{
    struct asm_publication *p = &o->publication;
    o->valid = 1;
    answer_waits(n, o);
    if (p->mode == ASM_PUB_EVERY_SET || (p->mode == ASM_PUB_NONE && o->kind == ASM_EVENT))
        publish(n, o);
    else if (p->mode == ASM_PUB_DEADBAND && fabsf(as_float(o) - p->last_value) > p->deadband) {
        if (due(n->now_ms, p->last_ms + p->min_gap_ms))
            publish(n, o);
        else
            p->pending = 1;
    }
}

int asm_node_write(struct asm_node *n, struct asm_object *o, const void *data, size_t length)
{
    if (length > o->capacity)
        return ASM_E_TOO_LARGE;
    if (length)
        memcpy(o->value, data, length);
    o->length = (uint16_t)length;
    changed(n, o);
    return ASM_OK;
}

static int check_value(const struct asm_object *o, const uint8_t *data, size_t length)
{
    if (length > o->capacity || asm_codec_check(o->descriptor, o->descriptor_length, data, length) != ASM_OK)
        return ASM_S_VALUE_ERROR;
    return ASM_S_OK;
}

static int set_value(struct asm_node *n, struct asm_object *o, const uint8_t *data, size_t length)
{
    int status = check_value(o, data, length);
    if (status != ASM_S_OK)
        return status;
    if (o->set != NULL)
        status = o->set(n, o, data, length);
    else {
        if (length)
            memcpy(o->value, data, length);
        o->length = (uint16_t)length;
    }
    if (status == ASM_S_OK)
        changed(n, o);
    return status;
}

/* -- serving requests -------------------------------------------------------------------------------------------- */

/* The LOOKUP reply data of ``o`` (section 3) in n->out + 4; its length. */
static size_t describe(struct asm_node *n, const struct asm_object *o)
{
    uint8_t *d = n->out + ASM_HEADER_SIZE;
    const char *class_name = o->class_name ? o->class_name : o->name;
    size_t name_length = length_of(o->name), class_length = length_of(class_name);
    uint8_t published = o->publication.mode != ASM_PUB_NONE || o->kind == ASM_EVENT;
    if (5u + o->descriptor_length + 1u + name_length + class_length > ASM_NODE_OUT - ASM_HEADER_SIZE)
        return 0;
    d[0] = o->class_id;
    d[1] = o->id;
    d[2] = o->kind;
    d[3] = (uint8_t)((o->flags & ~ASM_F_PUBLISHED) | (published ? ASM_F_PUBLISHED : 0));
    d[4] = o->descriptor_length;
    memcpy(d + 5, o->descriptor, o->descriptor_length);
    d += 5 + o->descriptor_length;
    *d++ = (uint8_t)name_length;
    memcpy(d, o->name, name_length);
    memcpy(d + name_length, class_name, class_length);
    return 5u + o->descriptor_length + 1u + name_length + class_length;
}

static int wait_for(struct asm_node *n, uint8_t source, const struct asm_message *m, struct asm_object *o)
{
    uint32_t ms = m->timeout < 0 ? UINT32_MAX : asm_timeout_ms((uint8_t)m->timeout);
    if (ms == 0)
        return ASM_S_TIMEOUT;
    for (unsigned k = 0; k < ASM_MAX_WAITS; k++) {
        struct asm_wait *w = &n->waits[k];
        if (w->used)
            continue;
        w->used = 1;
        w->source = source;
        w->txn = m->txn;
        w->method = m->method;
        w->object_byte = m->object_id;
        w->object = o;
        w->forever = ms == UINT32_MAX;
        w->deadline_ms = n->now_ms + (w->forever ? 0 : ms);
        return -1; /* answered later */
    }
    return ASM_S_BUSY;
}

/* Serve one request; returns the status of a reply to send with n->out + 4 holding ``*length`` bytes, or -1 when
 * the reply is sent later (a wait). */
static int execute(struct asm_node *n, uint8_t source, const struct asm_message *m, size_t *length)
{
    struct asm_object *o = NULL;
    *length = 0;
    if (m->method == ASM_LOOKUP && m->object_id == 0) {
        if (m->length == 0) {
            n->out[ASM_HEADER_SIZE] = n->count;
            *length = 1 + length_of(n->name);
            memcpy(n->out + ASM_HEADER_SIZE + 1, n->name, *length - 1);
            return ASM_S_OK;
        }
        if (!asm_utf8_valid(m->data, m->length))
            return ASM_S_BAD_MESSAGE;
        for (uint8_t k = 0; k < n->count && o == NULL; k++)
            if (length_of(n->objects[k]->name) == m->length && memcmp(n->objects[k]->name, m->data, m->length) == 0)
                o = n->objects[k];
        if (o == NULL)
            return ASM_S_NOT_FOUND;
        *length = describe(n, o);
        return ASM_S_OK;
    }
    if (m->object_id == 0) { /* a group request: the object of this class */
        for (uint8_t k = 0; k < n->count && o == NULL; k++)
            if (n->objects[k]->class_id == m->class_id)
                o = n->objects[k];
    } else if (m->object_id <= n->count) {
        o = n->objects[m->object_id - 1];
        if (m->method != ASM_LOOKUP && o->class_id != m->class_id)
            o = NULL;
    }
    if (o == NULL)
        return ASM_S_NOT_FOUND;
    if (m->method == ASM_LOOKUP) {
        *length = describe(n, o);
        return ASM_S_OK;
    }
    if ((ASM_WRITES >> m->method) & 1u) {
        if ((o->flags & ASM_F_READ_ONLY) && (m->method == ASM_SET || m->method == ASM_RESET))
            return ASM_S_READ_ONLY;
        if (n->estop && ((o->estop_refuses >> m->method) & 1u))
            return ASM_S_ESTOP;
    }
    if (o->kind == ASM_SERVICE) {
        switch (m->method) {
        case ASM_START:
            if (m->length > 0)
                return ASM_S_VALUE_ERROR; /* this runtime's services start without parameters */
            /* fall through */
        case ASM_STOP: case ASM_SUSPEND: case ASM_RESUME: case ASM_RESET:
            return o->control != NULL ? o->control(n, o, m->method) : ASM_S_UNSUPPORTED;
        case ASM_STATUS:
            n->out[ASM_HEADER_SIZE] = (uint8_t)((o->started ? 2 : 0) | (o->running ? 4 : 0) | (o->failed ? 8 : 0));
            *length = 1;
            return ASM_S_OK;
        default:
            return ASM_S_UNSUPPORTED;
        }
    }
    switch (m->method) {
    case ASM_GET:
        if (!o->valid && (o->flags & ASM_F_SYNC_GET))
            return wait_for(n, source, m, o);
        o->valid = 0;
        /* fall through */
    case ASM_PEEK:
        memcpy(n->out + ASM_HEADER_SIZE, o->value, o->length);
        *length = o->length;
        return ASM_S_OK;
    case ASM_SET:
        return set_value(n, o, m->data, m->length);
    case ASM_RESET:
        o->valid = 0;
        return o->set != NULL ? o->set(n, o, NULL, 0) : ASM_S_OK; /* a set of nothing: back to the initial value */
    case ASM_STATUS:
        n->out[ASM_HEADER_SIZE] = o->valid ? 1 : 0;
        *length = 1;
        return ASM_S_OK;
    case ASM_WAIT:
        return o->kind == ASM_EVENT ? wait_for(n, source, m, o) : ASM_S_UNSUPPORTED;
    default:
        return ASM_S_UNSUPPORTED;
    }
}

int asm_node_local(struct asm_node *n, const uint8_t *raw, size_t size)
{
    struct asm_message m;
    size_t length;
    if (asm_decode(raw, size, &m) != ASM_OK)
        return ASM_S_BAD_MESSAGE;
    int status = execute(n, n->node_id, &m, &length);
    return status < 0 ? ASM_S_OK : status;
}

static const char *explain(int status)
{
    switch (status) {
    case ASM_S_TIMEOUT: return "timed out";
    case ASM_S_SERVICE_ERROR: return "not in a state that allows it";
    case ASM_S_VALUE_ERROR: return "value out of its domain or malformed";
    case ASM_S_NOT_FOUND: return "no such object";
    case ASM_S_UNSUPPORTED: return "method not supported by this object";
    case ASM_S_BAD_MESSAGE: return "undecodable request data";
    case ASM_S_BUSY: return "too many waiting requests";
    case ASM_S_READ_ONLY: return "read-only: only the module writes it";
    case ASM_S_ESTOP: return "e-stop latched: release it first";
    default: return "";
    }
}

static void serve(struct asm_node *n, uint8_t source, const uint8_t *raw, size_t size)
{
    struct asm_message m;
    size_t length;
    int status;
    if (asm_decode(raw, size, &m) != ASM_OK) {
        n->dropped++;
        return;
    }
    if (m.kind != ASM_REQUEST && m.kind != ASM_REQUEST_REPLY)
        return; /* replies and publications: this node neither asks nor subscribes */
    n->served++;
    status = execute(n, source, &m, &length);
    if (status < 0 || m.kind != ASM_REQUEST_REPLY)
        return;
    if (status != ASM_S_OK) {
        const char *text = explain(status);
        reply(n, source, m.method, m.txn, (uint8_t)status, m.object_id, text, length_of(text));
    } else
        reply(n, source, m.method, m.txn, ASM_S_OK, m.object_id, n->out + ASM_HEADER_SIZE, length);
}

/* -- frames and time --------------------------------------------------------------------------------------------- */

static int accepts(const struct asm_node *n, const struct asm_can_id *id)
{
    switch (id->dest_kind) {
    case ASM_DEST_NODE:
        return id->dest == n->node_id;
    case ASM_DEST_GROUP:
        for (uint8_t k = 0; k < n->group_count; k++)
            if (n->groups[k] == id->dest)
                return 1;
        return 0;
    case ASM_DEST_BROADCAST:
        return id->priority != ASM_PRIORITY_PUBLICATION;
    default:
        return id->dest == ASM_SYSTEM_ESTOP;
    }
}

void asm_node_set_estop(struct asm_node *n, int latched)
{
    n->estop = latched ? 1 : 0;
    if (latched && n->on_estop != NULL)
        n->on_estop(n, n->estop_ctx);
}

void asm_node_frame(struct asm_node *n, uint32_t can_id, const uint8_t *data, uint8_t dlc, uint32_t now_ms)
{
    struct asm_can_id id;
    const uint8_t *message;
    size_t length;
    n->now_ms = now_ms;
    asm_can_unpack(can_id, &id);
    if (id.dest_kind == ASM_DEST_SYSTEM && id.dest == ASM_SYSTEM_ESTOP && (id.frame == ASM_SINGLE || id.frame == ASM_FIRST)) {
        asm_node_set_estop(n, 1); /* from any source, before anything else */
        return;
    }
    if (id.source == 0 || id.source == 255 || dlc > 64)
        return;
    if (id.dest_kind == ASM_DEST_BROADCAST && id.priority == ASM_PRIORITY_PUBLICATION) {
        struct asm_message m; /* what the module listens to: one-frame publications, never through the reassembler */
        if (n->on_publication != NULL && id.frame == ASM_SINGLE && asm_decode(data, dlc, &m) == ASM_OK &&
            m.kind == ASM_PUBLICATION)
            n->on_publication(n, id.source, &m);
        return;
    }
    if (!accepts(n, &id))
        return;
    if (id.frame == ASM_FIRST && dlc >= 8 && (size_t)(data[0] | data[1] << 8) > ASM_CAN_MAX_MESSAGE) {
        /* longer than this module takes: its header is in the first frame, so say so at once (TOO_LARGE) */
        static const char text[] = "message longer than this module takes";
        n->dropped++;
        if (asm_version_of(data[4]) == ASM_VERSION && asm_kind_of(data[4]) == ASM_REQUEST_REPLY)
            reply(n, id.source, (uint8_t)asm_method_of(data[4]), data[5] & ASM_MAX_TXN, ASM_S_TOO_LARGE, data[7], text,
                  sizeof text - 1);
        return;
    }
    if (asm_reassemble(&n->rx, &id, data, dlc, now_ms, &message, &length))
        serve(n, id.source, message, length);
}

void asm_node_poll(struct asm_node *n, uint32_t now_ms)
{
    n->now_ms = now_ms;
    if (due(now_ms, n->next_heartbeat_ms))
        heartbeat(n);
    for (unsigned k = 0; k < ASM_MAX_WAITS; k++) {
        struct asm_wait *w = &n->waits[k];
        if (w->used && !w->forever && due(now_ms, w->deadline_ms)) {
            const char *text = explain(ASM_S_TIMEOUT);
            w->used = 0;
            reply(n, w->source, w->method, w->txn, ASM_S_TIMEOUT, w->object_byte, text, length_of(text));
        }
    }
    for (uint8_t k = 0; k < n->count; k++) {
        struct asm_object *o = n->objects[k];
        struct asm_publication *p = &o->publication;
        if (p->mode != ASM_PUB_DEADBAND && p->mode != ASM_PUB_RATE)
            continue;
        if ((p->pending && due(now_ms, p->last_ms + p->min_gap_ms)) ||
            (p->refresh_ms && due(now_ms, p->last_ms + p->refresh_ms)))
            publish(n, o);
    }
    asm_reassembler_expire(&n->rx, now_ms);
}

void asm_node_leave(struct asm_node *n)
{
    static const uint8_t nothing[1] = {0};
    asm_node_send(n, ASM_DEST_SYSTEM, ASM_SYSTEM_LEAVE, nothing, 0, ASM_PRIORITY_HEARTBEAT);
}

void asm_node_send_estop(struct asm_node *n, const char *reason)
{
    size_t length = reason ? length_of(reason) : 0;
    struct asm_can_id id = {0};
    if (length > 8) { /* cut to 8 bytes, never inside a UTF-8 character */
        length = 8;
        while (length > 0 && ((uint8_t)reason[length] & 0xC0) == 0x80)
            length--;
    }
    id.dest_kind = ASM_DEST_SYSTEM;
    id.dest = ASM_SYSTEM_ESTOP;
    id.source = n->node_id;
    if (n->port.send(n->port.ctx, asm_can_pack(&id), (const uint8_t *)(length ? reason : ""), (uint8_t)length) != 0)
        n->send_errors++;
    asm_node_set_estop(n, 1);
}
