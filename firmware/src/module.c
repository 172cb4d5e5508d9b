#include "asm/module.h"

#include <math.h>
#include <string.h>

#include "asm/version.h"

#ifndef ASM_FW_BUILD
#define ASM_FW_BUILD 0u /* a build that was not stamped (asm_module/firmware_build.py stamps the sources' CRC-32) */
#endif

/* Each object's codec descriptor, from the module profile (contract/module.toml, asm/profile.h); the e-stop's is
 * ASM's. */
static const uint8_t D_GOAL[] = {ASM_D_JOINT_GOAL}, D_ANGLE[] = {ASM_D_JOINT_ANGLE}, D_TORQUE[] = {ASM_D_JOINT_TORQUE},
                     D_LIMITS[] = {ASM_D_JOINT_LIMITS}, D_SERVO[] = {ASM_D_SERVO_SERVICE},
                     D_CONTACT[] = {ASM_D_SENSOR_CONTACT}, D_ESTOP[] = {ASM_TAG_BOOL},
                     D_INFO[] = {ASM_D_MODULE_INFO}, D_CALIBRATION[] = {ASM_D_JOINT_CALIBRATION},
                     D_TYPE[] = {ASM_D_MODULE_TYPE};

static float clamp(float v, const float limits[2]) { return v < limits[0] ? limits[0] : v > limits[1] ? limits[1] : v; }

/* The calibration between the joint's raw angle and the module's (joint.calibration): every command and reading. */
static float raw_of(const struct asm_calibration *c, float degrees) { return c->zero + (float)c->direction * degrees; }

static void joint_read(struct asm_module *m, float *angle, float *torque, uint8_t *contact)
{
    m->joint.read(m->joint.ctx, angle, torque, contact);
    *angle = (float)m->cal.direction * (*angle - m->cal.zero);
    *torque *= (float)m->cal.direction;
}

static void command(struct asm_module *m)
{
    if (m->servo.running)
        m->joint.command(m->joint.ctx, raw_of(&m->cal, m->goal_v));
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
    float v[2] = {m->cal.min, m->cal.max}; /* RESET: the calibration's soft limits (within the hardware's range) */
    (void)o;
    if (length == 8)
        memcpy(v, data, 8);
    if (!(m->cal.min <= v[0] && v[0] < v[1] && v[1] <= m->cal.max))
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
    asm_gait_discard_staged(m); /* a deployment in progress is abandoned: deploy again after the release */
    joint_read(m, &m->goal_v, &torque, &contact); /* hold where it is now */
    m->goal_v = clamp(m->goal_v, m->limits_v);
    command(m);
}

static int set_estop(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    (void)o;
    if (length == 0)
        return ASM_S_VALUE_ERROR; /* a RESET does not release: a SET to false does, module by module */
    asm_node_set_estop(node, data[0] == 1); /* latching holds the joint; false releases */
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

int asm_calibration_check(const struct asm_module *m, const struct asm_calibration *c)
{
    if (!(isfinite(c->zero) && isfinite(c->min) && isfinite(c->max) && (c->direction == 1 || c->direction == -1)))
        return ASM_S_VALUE_ERROR; /* NaN and +-inf: refused, never clamped */
    float a = raw_of(c, c->min), b = raw_of(c, c->max);
    if (!(c->min < c->max && m->hardware[0] <= a && a <= m->hardware[1] && m->hardware[0] <= b && b <= m->hardware[1]))
        return ASM_S_VALUE_ERROR;
    return ASM_S_OK;
}

/* Apply a checked calibration. The joint stays where it is commanded: the goal becomes the same raw angle in the new
 * calibration (then clamped to the new limits, as a narrower joint.limits clamps it). */
static void calibrate(struct asm_module *m, const struct asm_calibration *c)
{
    float raw = raw_of(&m->cal, m->goal_v);
    m->cal = *c;
    m->limits_v[0] = c->min;
    m->limits_v[1] = c->max;
    m->goal_v = clamp((float)c->direction * (raw - c->zero), m->limits_v);
    memcpy(m->calibration_v, &c->zero, 4);
    m->calibration_v[4] = (uint8_t)c->direction;
    memcpy(m->calibration_v + 5, &c->min, 4);
    memcpy(m->calibration_v + 9, &c->max, 4);
    command(m);
}

int asm_module_calibrate(struct asm_module *m, const struct asm_calibration *c)
{
    int status = asm_calibration_check(m, c);
    if (status == ASM_S_OK)
        calibrate(m, c);
    return status;
}

void asm_module_set_store(struct asm_module *m, asm_calibration_store store, void *ctx)
{
    m->store = store;
    m->store_ctx = ctx;
}

static int set_calibration(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    struct asm_module *m = asm_module_of(node);
    struct asm_calibration c = {0.0f, 1, m->hardware[0], m->hardware[1]}; /* RESET: none */
    (void)o;
    if (length == ASM_CALIBRATION_BYTES) {
        memcpy(&c.zero, data, 4);
        c.direction = (int8_t)data[4];
        memcpy(&c.min, data + 5, 4);
        memcpy(&c.max, data + 9, 4);
    } else if (length != 0)
        return ASM_S_VALUE_ERROR;
    int status = asm_calibration_check(m, &c);
    if (status != ASM_S_OK)
        return status;
    if (m->store != 0 && m->store(m->store_ctx, &c) != 0)
        return ASM_S_INTERNAL; /* answered OK only once it would survive a reset */
    calibrate(m, &c);
    return ASM_S_OK;
}

static void put32(uint8_t *at, uint32_t v)
{
    for (int k = 0; k < 4; k++)
        at[k] = (uint8_t)(v >> (8 * k));
}

void asm_module_measured(struct asm_module *m, uint32_t tick_cycles, uint32_t stack_bytes)
{
    put32(m->info_v + 16, tick_cycles);
    put32(m->info_v + 20, stack_bytes);
}

static int type_char(char c, int first)
{
    int alnum = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9');
    return alnum || (!first && (c == '_' || c == '+' || c == '-'));
}

int asm_module_set_type(struct asm_module *m, const char *type)
{
    uint16_t n = 0;
    while (n <= ASM_TYPE_BYTES && type[n] != 0) { /* no strlen: a board links no C library string routine for it */
        if (n == ASM_TYPE_BYTES || !type_char(type[n], n == 0))
            return ASM_S_VALUE_ERROR; /* no type's name: module.type keeps what it said */
        n++;
    }
    memcpy(m->type_v, type, n);
    m->type.length = n;
    return ASM_S_OK;
}

static void info_init(struct asm_module *m)
{
    put32(m->info_v, ASM_FW_VERSION);
    put32(m->info_v + 4, ASM_FW_BUILD);
    m->info_v[8] = 1; /* the C runtime */
    m->info_v[9] = (uint8_t)ASM_MAX_STATES;
    m->info_v[10] = (uint8_t)(ASM_MAX_STATES >> 8);
    m->info_v[11] = (uint8_t)ASM_MAX_MODES;
    put32(m->info_v + 12, ASM_CAN_MAX_MESSAGE);
    asm_module_measured(m, 0, 0);
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
    m->cal = (struct asm_calibration){0.0f, 1, hardware_min, hardware_max};
    calibrate(m, &m->cal);
    m->goal_v = clamp(0.0f, m->limits_v);
    info_init(m);
    asm_object_init(&m->goal, "joint.goal", ASM_C_JOINT_GOAL, ASM_ATTRIBUTE, D_GOAL, sizeof D_GOAL, &m->goal_v, 4, 4);
    m->goal.set = set_goal;
    m->goal.estop_refuses = ASM_WRITES;
    asm_object_init(&m->angle, "joint.angle", ASM_C_JOINT_ANGLE, ASM_ATTRIBUTE, D_ANGLE, sizeof D_ANGLE, &m->angle_v, 4, 4);
    m->angle.flags = ASM_F_READ_ONLY;
    m->angle.publication = (struct asm_publication){.mode = ASM_PUB_DEADBAND, .deadband = 0.1f, .min_gap_ms = 40,
                                                    .refresh_ms = 500};
    asm_object_init(&m->torque, "joint.torque", ASM_C_JOINT_TORQUE, ASM_ATTRIBUTE, D_TORQUE, sizeof D_TORQUE, &m->torque_v, 4, 4);
    m->torque.flags = ASM_F_READ_ONLY;
    m->torque.publication = (struct asm_publication){.mode = ASM_PUB_DEADBAND, .deadband = 0.05f, .min_gap_ms = 80,
                                                     .refresh_ms = 1000};
    asm_object_init(&m->limits, "joint.limits", ASM_C_JOINT_LIMITS, ASM_ATTRIBUTE, D_LIMITS, sizeof D_LIMITS, m->limits_v, 8, 8);
    m->limits.set = set_limits;
    m->limits.estop_refuses = ASM_WRITES;
    asm_object_init(&m->servo, "servo.service", ASM_C_SERVO_SERVICE, ASM_SERVICE, D_SERVO, sizeof D_SERVO, NULL, 0, 0);
    m->servo.control = control_servo;
    m->servo.estop_refuses = ASM_WRITES;
    asm_object_init(&m->contact, "sensor.contact", ASM_C_SENSOR_CONTACT, ASM_ATTRIBUTE, D_CONTACT, sizeof D_CONTACT, &m->contact_v, 1, 1);
    m->contact.flags = ASM_F_READ_ONLY;
    m->contact.publication.mode = ASM_PUB_EVERY_SET;
    asm_object_init(&m->estop, "estop", ASM_CLASS_ESTOP, ASM_ATTRIBUTE, D_ESTOP, sizeof D_ESTOP, &m->estop_v, 1, 1);
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
    asm_object_init(&m->info, "module.info", ASM_C_MODULE_INFO, ASM_ATTRIBUTE, D_INFO, sizeof D_INFO, m->info_v,
                    ASM_INFO_BYTES, ASM_INFO_BYTES);
    m->info.flags = ASM_F_READ_ONLY;
    asm_object_init(&m->calibration, "joint.calibration", ASM_C_JOINT_CALIBRATION, ASM_ATTRIBUTE, D_CALIBRATION,
                    sizeof D_CALIBRATION, m->calibration_v, ASM_CALIBRATION_BYTES, ASM_CALIBRATION_BYTES);
    m->calibration.set = set_calibration;
    m->calibration.estop_refuses = ASM_WRITES;
    asm_object_init(&m->type, "module.type", ASM_C_MODULE_TYPE, ASM_ATTRIBUTE, D_TYPE, sizeof D_TYPE, m->type_v, 0,
                    ASM_TYPE_BYTES);
    m->type.flags = ASM_F_READ_ONLY;
    asm_node_register(&m->node, &m->info); /* after every object of the first versions: their IDs stay */
    asm_node_register(&m->node, &m->calibration);
    asm_node_register(&m->node, &m->type); /* and after those */
    control_servo(&m->node, &m->servo, ASM_START);
}

void asm_module_tick(struct asm_module *m, uint32_t now_ms)
{
    m->node.now_ms = now_ms;
    if (m->servo.running) {
        float angle, torque;
        uint8_t contact;
        joint_read(m, &angle, &torque, &contact);
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
