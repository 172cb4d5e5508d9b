#include "asm/gait.h"

#include <math.h>
#include <string.h>

#include "asm/module.h"

enum { C_TABLE = 0x20, C_PHASE = 0x21, C_DIRECTION = 0x22, C_STATE = 0x23, C_SERVICE = 0x24, C_TICK = 0x25,
       C_CHECKSUM = 0x26, C_STAGED = 0x27, C_STAGED_CHECKSUM = 0x28, C_ACTIVATE = 0x29, C_LEASE = 0x2A };
#define RAMP_MS 1000u
#define MAX_LEASE_SECONDS 60.0f
#define REANCHOR_MS 3600000u /* an hour: the elapsed milliseconds stay exact in a float */

static const uint8_t D_BYTES[] = {0x0D, 0x00}, D_UINT32[] = {0x08}, D_FLOAT32[] = {0x0A}, D_JSON[] = {0x10},
                     D_FLOAT64[] = {0x0B}, D_INT8[] = {0x02}, D_UINT16[] = {0x07},
                     D_LEASE[] = {0x0F, 0x03, 0x06, 'h', 'o', 'l', 'd', 'e', 'r', 0x0C, 0x00, 0x05, 't', 'o', 'k',
                                  'e', 'n', 0x08, 0x07, 's', 'e', 'c', 'o', 'n', 'd', 's', 0x0A};

/* A program this slice runs: one time-driven periodic mode (what a version-1 table says). */
static int periodic(const struct asm_program *p)
{
    if (p->modes_n != 1 || p->sequence_n > 1 || p->modes[0].one_shot)
        return 0;
    for (uint16_t k = 0; k < p->states_n; k++)
        if (p->states[k].event != ASM_EV_NONE || p->states[k].emit)
            return 0;
    return 1;
}

static int parse(struct asm_module *m, const uint8_t *data, size_t length, struct asm_program *into)
{
    if (asm_table_parse(data, length, m->limits_v, into) != ASM_OK || !periodic(into))
        return ASM_S_VALUE_ERROR;
    return ASM_S_OK;
}

/* -- the automaton ----------------------------------------------------------------------------------------------- */

static const struct asm_state *states(const struct asm_gait *g) { return g->program.states + g->program.modes[0].first; }
static uint16_t count(const struct asm_gait *g) { return g->program.modes[0].count; }

/* The state phase time ``tau`` falls in (bisect_right over the states' starts). */
static uint16_t state_at(const struct asm_gait *g, float tau, float *start)
{
    float at = 0.0f;
    uint16_t index = 0;
    *start = 0.0f;
    for (uint16_t k = 0; k < count(g); k++) {
        if (at <= tau) {
            index = k;
            *start = at;
        }
        at += states(g)[k].duration;
    }
    return index;
}

/* The state phase time tau falls in becomes gait.state (written on a change), and its reference, ramped in from
 * the goal held at the start, becomes the goal. */
static void output(struct asm_module *m, uint32_t now_ms)
{
    struct asm_gait *g = &m->gait;
    const struct asm_state *s = states(g);
    float start, previous, reference;
    uint16_t index = state_at(g, g->tau, &start);
    if (index != g->state_v || !g->state.valid)
        asm_node_write(&m->node, &g->state, &index, 2);
    reference = s[index].target;
    if (s[index].linear) {
        previous = s[(index + count(g) - 1) % count(g)].target;
        reference = previous + (g->tau - start) / s[index].duration * (s[index].target - previous);
    }
    uint32_t since = now_ms - g->ramp_start_ms;
    float ramp = since >= RAMP_MS ? 1.0f : (float)since / (float)RAMP_MS;
    asm_module_set_goal(m, g->ramp_from + ramp * (reference - g->ramp_from));
}

static void start(struct asm_module *m, uint32_t now_ms)
{
    struct asm_gait *g = &m->gait;
    g->period = 0.0f;
    for (uint16_t k = 0; k < count(g); k++)
        g->period += states(g)[k].duration;
    g->heading = g->direction_v;
    g->tau = g->tau0 = g->phase_v * g->period;
    g->t0_ms = g->last_tick_ms = now_ms;
    g->ramp_from = m->goal_v;
    g->ramp_start_ms = now_ms;
    g->service.started = g->service.running = 1;
    output(m, now_ms);
}

void asm_gait_tick(struct asm_module *m, uint32_t now_ms)
{
    struct asm_gait *g = &m->gait;
    g->tick_v = now_ms / 1000.0;
    asm_node_write(&m->node, &g->tick, &g->tick_v, 8);
    if (!g->service.running || m->node.estop)
        return;
    if (g->direction_v != g->heading || now_ms - g->t0_ms >= REANCHOR_MS) {
        g->tau0 = g->tau; /* a direction set directly applies from the previous tick on */
        g->t0_ms = g->last_tick_ms;
        g->heading = g->direction_v;
    }
    g->tau = fmodf(g->tau0 + (float)g->heading * ((float)(now_ms - g->t0_ms) / 1000.0f), g->period);
    if (g->tau < 0.0f)
        g->tau += g->period;
    g->last_tick_ms = now_ms;
    output(m, now_ms);
}

void asm_gait_halt(struct asm_module *m) { m->gait.service.started = m->gait.service.running = 0; }

static int control(struct asm_node *node, struct asm_object *o, uint8_t method)
{
    struct asm_module *m = asm_module_of(node);
    struct asm_gait *g = &m->gait;
    switch (method) {
    case ASM_START:
        if (o->started)
            return ASM_S_SERVICE_ERROR;
        start(m, node->now_ms);
        return ASM_S_OK;
    case ASM_STOP:
        asm_gait_halt(m);
        return ASM_S_OK;
    case ASM_SUSPEND:
        o->running = 0;
        return ASM_S_OK;
    case ASM_RESUME:
        if (o->started && !o->running) {
            g->tau0 = g->tau; /* the phase time goes on from where it paused */
            g->t0_ms = g->last_tick_ms = node->now_ms;
            o->running = 1;
        }
        return ASM_S_OK;
    default: /* RESET */
        return o->running ? ASM_S_SERVICE_ERROR : ASM_S_OK;
    }
}

/* -- the table and its settings ---------------------------------------------------------------------------------- */

static int set_table(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    struct asm_module *m = asm_module_of(node);
    struct asm_gait *g = &m->gait;
    if (g->service.started)
        return ASM_S_SERVICE_ERROR; /* a table never changes mid-cycle */
    if (length == 0 || parse(m, data, length, &g->program) != ASM_S_OK) {
        parse(m, g->table_v, g->table.length, &g->program); /* the table in force stays */
        return ASM_S_VALUE_ERROR;
    }
    memcpy(o->value, data, length);
    o->length = (uint16_t)length;
    g->checksum_v = asm_crc32(data, length);
    g->activate_v = 0; /* the gait is no longer a deployment's */
    return ASM_S_OK;
}

static int set_phase(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    float v = length == 4 ? asm_get_f32(data) : 0.0f; /* a RESET: 0 */
    (void)node;
    if (!(v >= 0.0f && v < 1.0f))
        return ASM_S_VALUE_ERROR;
    memcpy(o->value, &v, 4);
    return ASM_S_OK;
}

static int set_direction(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    int8_t v = length == 1 ? (int8_t)data[0] : 1;
    (void)node;
    if (v != 1 && v != -1)
        return ASM_S_VALUE_ERROR;
    memcpy(o->value, &v, 1);
    return ASM_S_OK;
}

/* -- a deployment: lease, staging, activation -------------------------------------------------------------------- */

static int lease_in_force(struct asm_module *m)
{
    return m->gait.lease_held && (int32_t)(m->gait.lease_expires_ms - m->node.now_ms) > 0;
}

static void lease_free(struct asm_gait *g)
{
    memset(g->lease_v, 0, 9); /* {holder "", token 0, seconds 0} */
    g->lease.length = 9;
    g->lease_held = 0;
    g->lease_token = 0;
}

static int set_lease(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    struct asm_module *m = asm_module_of(node);
    struct asm_gait *g = &m->gait;
    (void)o;
    if (length == 0) { /* RESET */
        lease_free(g);
        return ASM_S_OK;
    }
    uint8_t name = data[0];
    if (name >= 0x80 || length != 1u + name + 8u || name > ASM_LEASE_HOLDER)
        return ASM_S_VALUE_ERROR; /* a longer name (or a multi-byte length) than this module keeps */
    uint32_t token = asm_get_u32(data + 1 + name);
    float wanted = asm_get_f32(data + 5 + name);
    if (isnan(wanted))
        return ASM_S_VALUE_ERROR;
    if (node->estop && wanted > 0)
        return ASM_S_ESTOP;
    if (lease_in_force(m) && g->lease_token != token)
        return ASM_S_LOCKED;
    if (wanted <= 0 || name == 0) {
        lease_free(g);
        return ASM_S_OK;
    }
    float held = wanted < MAX_LEASE_SECONDS ? wanted : MAX_LEASE_SECONDS;
    memcpy(g->lease_v, data, 5u + name);
    memcpy(g->lease_v + 5 + name, &held, 4);
    g->lease.length = (uint16_t)(9u + name);
    g->lease_held = 1;
    g->lease_token = token;
    g->lease_expires_ms = node->now_ms + (uint32_t)(held * 1000.0f);
    return ASM_S_OK;
}

static int set_staged(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    struct asm_module *m = asm_module_of(node);
    struct asm_gait *g = &m->gait;
    if (length == 0) {
        g->staged_ok = 0;
        o->length = 0;
        g->staged_checksum_v = asm_crc32(data, 0);
        return ASM_S_OK;
    }
    if (length < 12 || data[0] != 'G' || data[1] != 'S' || data[2] != 1)
        return ASM_S_VALUE_ERROR;
    uint32_t id = asm_get_u32(data + 3);
    float phase = asm_get_f32(data + 7);
    int8_t direction = (int8_t)data[11];
    if (id == 0 || !(phase >= 0.0f && phase < 1.0f) || (direction != 1 && direction != -1))
        return ASM_S_VALUE_ERROR;
    if (lease_in_force(m) && g->lease_token != id)
        return ASM_S_LOCKED;
    if (parse(m, data + 12, length - 12, &g->staged_program) != ASM_S_OK) {
        g->staged_ok = 0;
        return ASM_S_VALUE_ERROR;
    }
    memcpy(o->value, data, length);
    o->length = (uint16_t)length;
    g->staged_ok = 1;
    g->staged_checksum_v = asm_crc32(data, length);
    return ASM_S_OK;
}

static int set_activate(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    struct asm_module *m = asm_module_of(node);
    struct asm_gait *g = &m->gait;
    uint32_t id = length == 4 ? asm_get_u32(data) : 0;
    (void)o;
    if (length == 0) { /* RESET */
        g->activate_v = 0;
        return ASM_S_OK;
    }
    if (id == g->activate_v && g->service.running)
        return ASM_S_OK; /* a resent activation: already running it */
    if (!g->staged_ok || asm_get_u32(g->staged_v + 3) != id)
        return ASM_S_VALUE_ERROR;
    asm_gait_halt(m);
    size_t table = g->staged.length - 12u;
    memcpy(g->table_v, g->staged_v + 12, table);
    g->table.length = (uint16_t)table;
    g->program = g->staged_program;
    g->checksum_v = asm_crc32(g->table_v, table);
    g->phase_v = asm_get_f32(g->staged_v + 7);
    g->direction_v = (int8_t)g->staged_v[11];
    g->activate_v = id;
    start(m, node->now_ms);
    return ASM_S_OK;
}

/* -- registration ------------------------------------------------------------------------------------------------ */

void asm_gait_register(struct asm_module *m, int part)
{
    static const uint8_t HOLD[] = {'G', 'T', 1, 1, 0, 0, 0, 0, 0, 0, 0, 0x80, 0x3F, 0}; /* hold 0 degrees */
    struct asm_gait *g = &m->gait;
    struct asm_node *n = &m->node;
    if (part == 0) {
        memcpy(g->table_v, HOLD, sizeof HOLD);
        parse(m, HOLD, sizeof HOLD, &g->program);
        g->checksum_v = asm_crc32(HOLD, sizeof HOLD);
        g->direction_v = g->heading = 1;
        asm_object_init(&g->table, "gait.table", C_TABLE, ASM_ATTRIBUTE, D_BYTES, 2, g->table_v, sizeof HOLD, ASM_TABLE_BYTES);
        g->table.set = set_table;
        g->table.estop_refuses = ASM_WRITES;
        asm_object_init(&g->checksum, "gait.checksum", C_CHECKSUM, ASM_ATTRIBUTE, D_UINT32, 1, &g->checksum_v, 4, 4);
        g->checksum.flags = ASM_F_READ_ONLY;
        asm_object_init(&g->phase, "gait.phase", C_PHASE, ASM_ATTRIBUTE, D_FLOAT32, 1, &g->phase_v, 4, 4);
        g->phase.set = set_phase;
        asm_object_init(&g->service, "gait.service", C_SERVICE, ASM_SERVICE, D_JSON, 1, NULL, 0, 0);
        g->service.control = control;
        g->service.estop_refuses = (1u << ASM_START) | (1u << ASM_RESUME);
        asm_object_init(&g->tick, "gait.tick", C_TICK, ASM_EVENT, D_FLOAT64, 1, &g->tick_v, 8, 8);
        g->tick.flags = ASM_F_READ_ONLY | ASM_F_SYNC_GET; /* an event: a GET waits for a firing */
        g->tick.publication = (struct asm_publication){.mode = ASM_PUB_RATE, .refresh_ms = 1000};
        struct asm_object *all[] = {&g->table, &g->checksum, &g->phase, &g->service, &g->tick};
        for (size_t k = 0; k < sizeof all / sizeof all[0]; k++)
            asm_node_register(n, all[k]);
    } else if (part == 1) {
        asm_object_init(&g->staged, "gait.staged", C_STAGED, ASM_ATTRIBUTE, D_BYTES, 2, g->staged_v, 0, ASM_STAGED_BYTES);
        g->staged.set = set_staged;
        g->staged.estop_refuses = ASM_WRITES;
        g->staged_checksum_v = asm_crc32(g->staged_v, 0);
        asm_object_init(&g->staged_checksum, "gait.staged_checksum", C_STAGED_CHECKSUM, ASM_ATTRIBUTE, D_UINT32, 1,
               &g->staged_checksum_v, 4, 4);
        g->staged_checksum.flags = ASM_F_READ_ONLY;
        asm_object_init(&g->activate, "gait.activate", C_ACTIVATE, ASM_ATTRIBUTE, D_UINT32, 1, &g->activate_v, 4, 4);
        g->activate.set = set_activate;
        g->activate.estop_refuses = ASM_WRITES;
        asm_object_init(&g->lease, "gait.lease", C_LEASE, ASM_ATTRIBUTE, D_LEASE, sizeof D_LEASE, g->lease_v, 0,
               sizeof g->lease_v);
        g->lease.set = set_lease;
        lease_free(g);
        struct asm_object *all[] = {&g->staged, &g->staged_checksum, &g->activate, &g->lease};
        for (size_t k = 0; k < sizeof all / sizeof all[0]; k++)
            asm_node_register(n, all[k]);
    } else {
        asm_object_init(&g->direction, "gait.direction", C_DIRECTION, ASM_ATTRIBUTE, D_INT8, 1, &g->direction_v, 1, 1);
        g->direction.set = set_direction;
        asm_object_init(&g->state, "gait.state", C_STATE, ASM_ATTRIBUTE, D_UINT16, 1, &g->state_v, 2, 2);
        g->state.flags = ASM_F_READ_ONLY;
        g->state.publication.mode = ASM_PUB_EVERY_SET;
        asm_node_register(n, &g->direction);
        asm_node_register(n, &g->state);
    }
}
