/* A module's objects (docs/protocol.md section 9) on an asm_node: the joint, its limits, the servo, contact, the
 * latched e-stop and the gait (asm/gait.h). The joint itself is behind a port of three calls, so the same code drives a simulated actuator
 * (the host library, asm_module/c_module.py) or a board's servo. */
#ifndef ASM_MODULE_H
#define ASM_MODULE_H

#include <stdint.h>

#include "asm/gait.h"
#include "asm/node.h"

struct asm_joint_port {
    void (*command)(void *ctx, float degrees); /* drive towards ``degrees`` (within the limits) */
    void (*relax)(void *ctx);                  /* servo off: the joint goes limp */
    void (*read)(void *ctx, float *angle, float *torque, uint8_t *contact);
    void *ctx;
};

/* joint.calibration (docs/protocol.md section 9): the angle the module reports is direction * (raw - zero), the raw
 * angle it commands zero + direction * goal; (min, max) are its soft limits, within which joint.limits may be set. */
struct asm_calibration {
    float zero;
    int8_t direction;
    float min, max;
};
#define ASM_CALIBRATION_BYTES 13u /* on the wire: record{zero:float32,direction:int8,min:float32,max:float32} */
#define ASM_INFO_BYTES 24u        /* module.info's record */
#define ASM_TYPE_BYTES 32u        /* module.type: str<32> */

/* Where a port keeps the calibration across resets (a board: its settings flash); nonzero: not stored. */
typedef int (*asm_calibration_store)(void *ctx, const struct asm_calibration *calibration);

struct asm_module {
    struct asm_node node;
    struct asm_joint_port joint;
    float hardware[2]; /* the joint's raw range: the calibration's limits lie within it */
    struct asm_object goal, angle, torque, limits, servo, contact, estop;
    float goal_v, angle_v, torque_v, limits_v[2];
    uint8_t contact_v, estop_v;
    struct asm_gait gait;
    struct asm_object info, calibration;
    struct asm_calibration cal;
    uint8_t info_v[ASM_INFO_BYTES], calibration_v[ASM_CALIBRATION_BYTES];
    asm_calibration_store store;
    void *store_ctx;
    struct asm_object type; /* module.type: what the module is, as a gait's robot description names its type */
    uint8_t type_v[ASM_TYPE_BYTES];
    uint8_t reset_pending; /* a firmware install's reset follows (the port's update): no gait starts, LOCKED */
};

/* The module a node belongs to (the node is its first member): what an object's set or control function needs. */
static inline struct asm_module *asm_module_of(struct asm_node *node) { return (struct asm_module *)(void *)node; }

/* Register the objects, start the servo and send the first heartbeat. ``hardware`` is also the initial limits. */
void asm_module_init(struct asm_module *m, const char *name, uint8_t node_id, const struct asm_port *port,
                     const struct asm_joint_port *joint, float hardware_min, float hardware_max, uint32_t now_ms);
/* Check ``c`` against the hardware's range (finite, direction +-1, min < max, both limits' raw angles within it):
 * 0, or ASM_S_VALUE_ERROR. */
int asm_calibration_check(const struct asm_module *m, const struct asm_calibration *c);
/* Run under calibration ``c`` (checked; not stored: what a port read back from its flash at boot), its limits the
 * joint's: ASM_S_OK or ASM_S_VALUE_ERROR. */
int asm_module_calibrate(struct asm_module *m, const struct asm_calibration *c);
/* Store every calibration set over the bus through ``store`` before it is answered OK. */
void asm_module_set_store(struct asm_module *m, asm_calibration_store store, void *ctx);
/* What a port measured itself for module.info: the worst control tick in cycles and the stack's high-water mark. */
void asm_module_measured(struct asm_module *m, uint32_t tick_cycles, uint32_t stack_bytes);
/* The module type ``module.type`` reports (a board's port passes its constant after asm_module_init; empty until
 * then: the module does not say): ASM_S_OK, or ASM_S_VALUE_ERROR, the type unchanged, for a name that is no type's
 * (1 to ASM_TYPE_BYTES letters, digits, '_', '+' or '-', the first a letter or digit; "" says none). */
int asm_module_set_type(struct asm_module *m, const char *type);
/* Command the joint to ``degrees``, clamped to joint.limits (the gait's output, a hold). */
void asm_module_set_goal(struct asm_module *m, float degrees);
/* One control tick: read the joint into joint.angle, joint.torque and sensor.contact (published by their policies),
 * then the node's timers. */
void asm_module_tick(struct asm_module *m, uint32_t now_ms);

#endif
