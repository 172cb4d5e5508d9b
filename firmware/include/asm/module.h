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

struct asm_module {
    struct asm_node node;
    struct asm_joint_port joint;
    float hardware[2]; /* the range joint.limits may be set within */
    struct asm_object goal, angle, torque, limits, servo, contact, estop;
    float goal_v, angle_v, torque_v, limits_v[2];
    uint8_t contact_v, estop_v;
    struct asm_gait gait;
};

/* The module a node belongs to (the node is its first member): what an object's set or control function needs. */
static inline struct asm_module *asm_module_of(struct asm_node *node) { return (struct asm_module *)(void *)node; }

/* Register the objects, start the servo and send the first heartbeat. ``hardware`` is also the initial limits. */
void asm_module_init(struct asm_module *m, const char *name, uint8_t node_id, const struct asm_port *port,
                     const struct asm_joint_port *joint, float hardware_min, float hardware_max, uint32_t now_ms);
/* Command the joint to ``degrees``, clamped to joint.limits (the gait's output, a hold). */
void asm_module_set_goal(struct asm_module *m, float degrees);
/* One control tick: read the joint into joint.angle, joint.torque and sensor.contact (published by their policies),
 * then the node's timers. */
void asm_module_tick(struct asm_module *m, uint32_t now_ms);

#endif
