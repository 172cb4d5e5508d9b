#include "asm/module.h"

#include <math.h>
#include <string.h>

enum { C_ESTOP = 0x03, C_GOAL = 0x10, C_ANGLE = 0x11, C_LIMITS = 0x12, C_TORQUE = 0x13, C_SERVO = 0x14,
       C_CONTACT = 0x30 };

static const uint8_t D_BOOL[] = {0x01}, D_FLOAT32[] = {0x0A}, D_LIMITS[] = {0x0E, 0x0A, 0x02}, D_JSON[] = {0x10};

static float clamp(float v, const float limits[2]) { return v < limits[0] ? limits[0] : v > limits[1] ? limits[1] : v; }

static void command(struct asm_module *m)
{
    if (m->servo.running)
        m->joint.command(m->joint.ctx, m->goal_v);
}

static int set_goal(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    struct asm_module *m = asm_module_of(node);
    float v = 0.0f;
    (void)o;
    if (length == 4)
        memcpy(&v, data, 4);
    if (!isfinite(v))
        return ASM_S_VALUE_ERROR; /* NaN and ±inf: a goal is a finite number of degrees */
    m->goal_v = clamp(v, m->limits_v); /* a RESET (no data) goes back to 0°, clamped */
    command(m);
    return ASM_S_OK;
}

static int set_limits(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    struct asm_module *m = asm_module_of(node);
    float v[2];
    (void)o;
    if (length == 0) { /* RESET: the hardware's range */
        v[0] = m->hardware[0];
        v[1] = m->hardware[1];
    } else
        memcpy(v, data, 8);
    if (!(m->hardware[0] <= v[0] && v[0] < v[1] && v[1] <= m->hardware[1]))
        return ASM_S_VALUE_ERROR;
    memcpy(m->limits_v, v, 8);
    m->goal_v = clamp(m->goal_v, m->limits_v);
    command(m);
    return ASM_S_OK;
}

void asm_module_set_goal(struct asm_module *m, float degrees)
{
    m->goal_v = clamp(degrees, m->limits_v);
    command(m);
}

static void hold(struct asm_node *node, void *ctx)
{
    struct asm_module *m = asm_module_of(node);
    float torque;
    uint8_t contact;
    (void)ctx;
    m->estop_v = 1;
    asm_gait_halt(m);
    m->joint.read(m->joint.ctx, &m->goal_v, &torque, &contact); /* hold where it is now */
    m->goal_v = clamp(m->goal_v, m->limits_v);
    command(m);
}

static int set_estop(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    (void)o;
    asm_node_set_estop(node, length == 1 && data[0] == 1); /* latching holds the joint; false releases */
    asm_module_of(node)->estop_v = node->estop;
    return ASM_S_OK;
}

static int control_servo(struct asm_node *node, struct asm_object *o, uint8_t method)
{
    struct asm_module *m = asm_module_of(node);
    switch (method) {
    case ASM_START:
        if (o->started)
            return ASM_S_SERVICE_ERROR;
        o->started = o->running = 1;
        command(m);
        return ASM_S_OK;
    case ASM_STOP:
        if (o->started)
            m->joint.relax(m->joint.ctx);
        o->started = o->running = 0;
        return ASM_S_OK;
    case ASM_SUSPEND:
        o->running = 0;
        return ASM_S_OK;
    case ASM_RESUME:
        o->running = o->started;
        command(m);
        return ASM_S_OK;
    default: /* RESET */
        return o->running ? ASM_S_SERVICE_ERROR : ASM_S_OK;
    }
}

void asm_module_init(struct asm_module *m, const char *name, uint8_t node_id, const struct asm_port *port,
                     const struct asm_joint_port *joint, float hardware_min, float hardware_max, uint32_t now_ms)
{
    memset(m, 0, sizeof *m);
    asm_node_init(&m->node, name, node_id, port, now_ms);
    m->node.on_estop = hold;
    m->joint = *joint;
    m->hardware[0] = m->limits_v[0] = hardware_min;
    m->hardware[1] = m->limits_v[1] = hardware_max;
    m->goal_v = clamp(0.0f, m->limits_v);
    asm_object_init(&m->goal, "joint.goal", C_GOAL, ASM_ATTRIBUTE, D_FLOAT32, 1, &m->goal_v, 4, 4);
    m->goal.set = set_goal;
    m->goal.estop_refuses = ASM_WRITES;
    asm_object_init(&m->angle, "joint.angle", C_ANGLE, ASM_ATTRIBUTE, D_FLOAT32, 1, &m->angle_v, 4, 4);
    m->angle.flags = ASM_F_READ_ONLY;
    m->angle.publication = (struct asm_publication){.mode = ASM_PUB_DEADBAND, .deadband = 0.1f, .min_gap_ms = 40,
                                                    .refresh_ms = 500};
    asm_object_init(&m->torque, "joint.torque", C_TORQUE, ASM_ATTRIBUTE, D_FLOAT32, 1, &m->torque_v, 4, 4);
    m->torque.flags = ASM_F_READ_ONLY;
    m->torque.publication = (struct asm_publication){.mode = ASM_PUB_DEADBAND, .deadband = 0.05f, .min_gap_ms = 80,
                                                     .refresh_ms = 1000};
    asm_object_init(&m->limits, "joint.limits", C_LIMITS, ASM_ATTRIBUTE, D_LIMITS, 3, m->limits_v, 8, 8);
    m->limits.set = set_limits;
    m->limits.estop_refuses = ASM_WRITES;
    asm_object_init(&m->servo, "servo.service", C_SERVO, ASM_SERVICE, D_JSON, 1, NULL, 0, 0);
    m->servo.control = control_servo;
    m->servo.estop_refuses = ASM_WRITES;
    asm_object_init(&m->contact, "sensor.contact", C_CONTACT, ASM_ATTRIBUTE, D_BOOL, 1, &m->contact_v, 1, 1);
    m->contact.flags = ASM_F_READ_ONLY;
    m->contact.publication.mode = ASM_PUB_EVERY_SET;
    asm_object_init(&m->estop, "estop", C_ESTOP, ASM_ATTRIBUTE, D_BOOL, 1, &m->estop_v, 1, 1);
    m->estop.set = set_estop;
    /* the order of the Python module, so object IDs match (docs/protocol.md's example: gait.checksum is 7) */
    struct asm_object *joint_objects[] = {&m->goal, &m->angle, &m->torque, &m->limits, &m->servo};
    for (size_t k = 0; k < sizeof joint_objects / sizeof joint_objects[0]; k++)
        asm_node_register(&m->node, joint_objects[k]);
    asm_gait_register(m, 0);
    asm_node_register(&m->node, &m->contact);
    asm_node_register(&m->node, &m->estop);
    asm_gait_register(m, 1);
    asm_gait_register(m, 2);
    control_servo(&m->node, &m->servo, ASM_START);
}

void asm_module_tick(struct asm_module *m, uint32_t now_ms)
{
    m->node.now_ms = now_ms;
    if (m->servo.running) {
        float angle, torque;
        uint8_t contact;
        m->joint.read(m->joint.ctx, &angle, &torque, &contact);
        asm_node_write(&m->node, &m->angle, &angle, 4);
        asm_node_write(&m->node, &m->torque, &torque, 4);
        if ((contact != 0) != (m->contact_v != 0)) {
            contact = contact ? 1 : 0;
            asm_node_write(&m->node, &m->contact, &contact, 1);
        }
    }
    asm_gait_tick(m, now_ms);
    asm_node_poll(&m->node, now_ms);
}
