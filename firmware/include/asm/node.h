/* An ASM node on a CAN bus (docs/protocol.md sections 1-5 and 7): the lookup table of a module's objects and the
 * server side of the protocol, without allocation, threads or an OS.
 *
 * The platform delivers frames (asm_node_frame) and calls asm_node_poll every few milliseconds with a monotonic
 * time in milliseconds; the node sends frames through its port. Everything a module stores lives in its objects'
 * own buffers, so the limits below are the whole of the node's RAM besides them. A request that cannot be served
 * within them is answered with the status the Python node gives (BUSY, NOT_FOUND, TOO_LARGE), never dropped
 * silently. */
#ifndef ASM_NODE_H
#define ASM_NODE_H

#include <stddef.h>
#include <stdint.h>

#include "asm/can.h"
#include "asm/wire.h"

#ifndef ASM_MAX_OBJECTS
#define ASM_MAX_OBJECTS 32 /* objects in the lookup table (IDs 1..ASM_MAX_OBJECTS) */
#endif
#ifndef ASM_MAX_WAITS
#define ASM_MAX_WAITS 4 /* requests waiting at once (WAIT on an event, GET of a sync_get attribute) */
#endif
#ifndef ASM_MAX_GROUPS
#define ASM_MAX_GROUPS 4 /* groups joined */
#endif
#ifndef ASM_NODE_OUT
#define ASM_NODE_OUT 1536u /* the longest reply or publication this node builds (a 64-state gait table fits) */
#endif

/* Statuses (enum asm_status), methods (enum asm_method, ASM_WRITES: the methods that change an object, what a
 * read-only attribute or a latched e-stop may refuse), object kinds and lookup flags (ASM_F_*) are in the generated
 * asm/contract.h, included by asm/wire.h. */

/* When a published attribute sends (section 5): every set; a float32 moving beyond a deadband at most every
 * min_gap_ms and at least every refresh_ms; or only every refresh_ms (an event that fires at every control tick). */
enum asm_publish_mode { ASM_PUB_NONE = 0, ASM_PUB_EVERY_SET = 1, ASM_PUB_DEADBAND = 2, ASM_PUB_RATE = 3 };

struct asm_node;
struct asm_object;

/* A remote SET of ``obj``, its bytes already a value of the object's codec and within its capacity: check its
 * domain and store it; an asm_status. NULL: a copy. */
typedef int (*asm_set_fn)(struct asm_node *node, struct asm_object *obj, const uint8_t *data, size_t length);
/* START/STOP/SUSPEND/RESUME/RESET of a service: an asm_status (SERVICE_ERROR when the state forbids it). */
typedef int (*asm_control_fn)(struct asm_node *node, struct asm_object *obj, uint8_t method);

struct asm_publication {
    uint8_t mode;       /* enum asm_publish_mode */
    uint8_t seq;        /* sequence number of the next publication, mod 128 */
    uint8_t pending;    /* a change not sent yet (it came inside min_gap_ms) */
    uint16_t min_gap_ms, refresh_ms;
    float deadband;
    float last_value;
    uint32_t last_ms;
};

struct asm_object {
    const char *name;
    const char *class_name; /* NULL: the name */
    uint8_t class_id;
    uint8_t kind;  /* enum asm_object_kind */
    uint8_t flags; /* ASM_F_SYNC_GET, ASM_F_SYNC_SET, ASM_F_READ_ONLY (ASM_F_PUBLISHED follows the policy) */
    const uint8_t *descriptor; /* the codec (section 2): the one statement of the type; a remote SET must match it */
    uint8_t descriptor_length;
    uint8_t *value;   /* the value's bytes, owned by the module */
    uint16_t length;  /* bytes in use */
    uint16_t capacity;
    uint8_t valid;
    uint16_t estop_refuses; /* bit (1 << method): refused with ESTOP while the node's e-stop is latched */
    asm_set_fn set;
    asm_control_fn control;
    uint8_t started, running, failed; /* services */
    struct asm_publication publication;
    uint8_t id; /* assigned by asm_node_register */
};

/* The platform: send one extended CAN frame. Nonzero when the frame could not be queued. */
struct asm_port {
    int (*send)(void *ctx, uint32_t id, const uint8_t *data, uint8_t dlc);
    void *ctx;
    uint8_t fd; /* CAN FD frames of 64 bytes */
};

struct asm_wait {
    uint8_t used, source, txn, method, object_byte, forever;
    struct asm_object *object;
    uint32_t deadline_ms;
};

struct asm_node {
    struct asm_port port;
    const char *name;
    uint8_t node_id;
    uint8_t count;
    struct asm_object *objects[ASM_MAX_OBJECTS];
    uint8_t groups[ASM_MAX_GROUPS];
    uint8_t group_count;
    struct asm_wait waits[ASM_MAX_WAITS];
    struct asm_reassembler rx;
    uint8_t out[ASM_NODE_OUT];
    uint8_t estop; /* latched */
    void (*on_estop)(struct asm_node *node, void *ctx); /* the module's reaction: stop the gait, hold the joint */
    void *estop_ctx;
    /* A one-frame publication another node broadcast (a neighbour's gait.state); NULL: publications are ignored. */
    void (*on_publication)(struct asm_node *node, uint8_t source, const struct asm_message *publication);
    uint16_t heartbeat_ms;
    uint32_t next_heartbeat_ms;
    uint32_t now_ms;
    uint32_t served, dropped, send_errors;
};

/* Fill in ``obj`` (everything else zero, the value valid): the one way the modules describe their objects. */
void asm_object_init(struct asm_object *obj, const char *name, uint8_t class_id, uint8_t kind,
                     const uint8_t *descriptor, uint8_t descriptor_length, void *value, uint16_t length,
                     uint16_t capacity);

void asm_node_init(struct asm_node *node, const char *name, uint8_t node_id, const struct asm_port *port,
                   uint32_t now_ms);
/* Enter ``obj`` (ID = its place); ASM_OK, ASM_E_TOO_LARGE when the table is full, ASM_E_RANGE for a name taken. */
int asm_node_register(struct asm_node *node, struct asm_object *obj);
struct asm_object *asm_node_find(struct asm_node *node, const char *name);
/* Join the group with CAN group ID ``group``; ASM_E_TOO_LARGE beyond ASM_MAX_GROUPS. */
int asm_node_join(struct asm_node *node, uint8_t group);

/* One received frame (extended identifier), at ``now_ms``. */
void asm_node_frame(struct asm_node *node, uint32_t id, const uint8_t *data, uint8_t dlc, uint32_t now_ms);
/* A request message from the module itself (its application, a test harness): served with every check a remote
 * one gets, without a reply; an asm_status. */
int asm_node_local(struct asm_node *node, const uint8_t *message, size_t length);
/* Heartbeats, publications due, waits that time out, stale partial messages. */
void asm_node_poll(struct asm_node *node, uint32_t now_ms);

/* The module's own write of an attribute or firing of an event: stores the value, answers waiting requests and
 * publishes by the object's policy. ASM_E_TOO_LARGE over its capacity. */
int asm_node_write(struct asm_node *node, struct asm_object *obj, const void *data, size_t length);
/* Latch (or release) the e-stop; latching calls on_estop. */
void asm_node_set_estop(struct asm_node *node, int latched);
/* Tell the bus this node leaves (system frame LEAVE). */
void asm_node_leave(struct asm_node *node);
/* Send ``msg`` (fragmented if it must be) to a node, a group or everyone (dest_kind: enum asm_dest_kind). */
void asm_node_send(struct asm_node *node, uint8_t dest_kind, uint8_t dest, const uint8_t *msg, size_t length,
                   uint8_t priority);
/* Send an e-stop to every node (system frame, priority 0, one frame). */
void asm_node_send_estop(struct asm_node *node, const char *reason);

#endif
