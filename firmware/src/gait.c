#include "asm/gait.h"

#include <math.h>
#include <stddef.h>
#include <string.h>

#include "asm/module.h"


/* Each object's codec descriptor, from the module profile (contract/module.toml, asm/profile.h). */
static const uint8_t D_TABLE[] = {ASM_D_GAIT_TABLE},
                     D_CHECKSUM[] = {ASM_D_GAIT_CHECKSUM},
                     D_PHASE[] = {ASM_D_GAIT_PHASE},
                     D_SERVICE[] = {ASM_D_GAIT_SERVICE},
                     D_TICK[] = {ASM_D_GAIT_TICK},
                     D_STAGED[] = {ASM_D_GAIT_STAGED},
                     D_STAGED_CHECKSUM[] = {ASM_D_GAIT_STAGED_CHECKSUM},
                     D_ACTIVATE[] = {ASM_D_GAIT_ACTIVATE},
                     D_LEASE[] = {ASM_D_GAIT_LEASE},
                     D_DIRECTION[] = {ASM_D_GAIT_DIRECTION},
                     D_STATE[] = {ASM_D_GAIT_STATE},
                     D_SWITCH[] = {ASM_D_GAIT_SWITCH},
                     D_CYCLE[] = {ASM_D_GAIT_CYCLE},
                     D_MODE[] = {ASM_D_GAIT_MODE},
                     D_DONE[] = {ASM_D_GAIT_DONE},
                     D_SIGNAL[] = {ASM_D_GAIT_SIGNAL};

/* ASM_S_OK if this module can run table ``data``: well formed, within the joint's limits and the module's own. */
static int check(struct asm_module *m, const uint8_t *data, size_t length)
{
    if (asm_table_parse(data, length, m->limits_v, NULL) != ASM_OK)
        return ASM_S_VALUE_ERROR;
    return asm_program_fits(m, data, length);
}

/* Make table ``data`` (already checked) the module's: its bytes, its program, its checksum. */
static void load_table(struct asm_module *m, const uint8_t *data, size_t length)
{
    struct asm_gait *g = &m->gait;
    memcpy(g->table_v, data, length);
    g->table.length = (uint16_t)length;
    asm_table_parse(g->table_v, length, m->limits_v, &g->program);
    asm_program_loaded(m);
    g->checksum_v = asm_crc32(g->table_v, length);
}

void asm_gait_tick(struct asm_module *m, uint32_t now_ms)
{
    struct asm_gait *g = &m->gait;
    g->tick_v = asm_seconds_f64(now_ms); /* a float64's bits: little-endian targets store it as the wire does */
    asm_node_write(&m->node, &g->tick, &g->tick_v, 8);
    asm_program_tick(m, now_ms);
}

void asm_gait_halt(struct asm_module *m) { m->gait.service.started = m->gait.service.running = 0; }

void asm_gait_discard_staged(struct asm_module *m)
{
    m->gait.staged_ok = 0;
    m->gait.staged.length = 0;
    m->gait.staged_checksum_v = asm_crc32(m->gait.staged_v, 0);
}

static int control(struct asm_node *node, struct asm_object *o, uint8_t method)
{
    struct asm_module *m = asm_module_of(node);
    switch (method) {
    case ASM_START:
        if (m->reset_pending)
            return ASM_S_LOCKED; /* an update's reset is 0.1 s away: it would drop the joint mid-step */
        if (o->started)
            return ASM_S_SERVICE_ERROR;
        asm_program_start(m, node->now_ms);
        return ASM_S_OK;
    case ASM_STOP:
        asm_gait_halt(m);
        return ASM_S_OK;
    case ASM_SUSPEND:
        if (o->running)
            asm_program_suspend(m);
        o->running = 0;
        return ASM_S_OK;
    case ASM_RESUME:
        if (m->reset_pending)
            return ASM_S_LOCKED;
        if (o->started && !o->running) {
            asm_program_resume(m, node->now_ms); /* the program goes on from where it paused */
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
    (void)o;
    if (length == 0 || check(m, data, length) != ASM_S_OK)
        return ASM_S_VALUE_ERROR; /* the table in force stays */
    load_table(m, data, length);
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
    if (length == 0) { /* RESET: like a release, which names no token: only a lease no longer in force */
        if (lease_in_force(m))
            return ASM_S_LOCKED;
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
    float held = wanted < ASM_MAX_LEASE_S ? wanted : ASM_MAX_LEASE_S;
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
        if (lease_in_force(m))
            return ASM_S_LOCKED; /* an empty value names no deploy ID: nobody clears under another's lease */
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
    if (check(m, data + 12, length - 12) != ASM_S_OK)
        return ASM_S_VALUE_ERROR; /* refused: what was staged stays staged */
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
    if (id == g->activate_v)
        return ASM_S_OK; /* a resent activation: done once, never a restart (an e-stop may have stopped it) */
    if (!g->staged_ok || asm_get_u32(g->staged_v + 3) != id)
        return ASM_S_VALUE_ERROR;
    if (m->reset_pending)
        return ASM_S_LOCKED; /* an update's reset follows: not started, to stop mid-step */
    size_t table = g->staged.length - 12u;
    if (check(m, g->staged_v + 12, table) != ASM_S_OK)
        return ASM_S_VALUE_ERROR; /* the joint limits changed since it was staged */
    asm_gait_halt(m);
    load_table(m, g->staged_v + 12, table);
    g->phase_v = asm_get_f32(g->staged_v + 7);
    g->direction_v = (int8_t)g->staged_v[11];
    g->activate_v = id;
    asm_program_start(m, node->now_ms);
    return ASM_S_OK;
}

/* -- a program's switches and signals, and its neighbours' states ------------------------------------------------ */

static const uint8_t SWITCH_INITIAL[6] = {0, 1, 0, 0, 0, 0}; /* {mode 0, direction 1, after 0} */

static int set_switch(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    struct asm_module *m = asm_module_of(node);
    struct asm_run *r = &m->gait.run;
    if (length == 0)
        data = SWITCH_INITIAL; /* a RESET */
    float after = asm_get_f32(data + 2);
    int8_t direction = (int8_t)data[1];
    if (data[0] >= m->gait.program.modes_n || (direction != 1 && direction != -1) || !isfinite(after))
        return ASM_S_VALUE_ERROR;
    memcpy(o->value, data, 6);
    o->length = 6;
    r->after_us = asm_us_of(after);
    r->switch_mode = data[0];
    r->switch_direction = direction;
    r->switch_pending = 1;
    return ASM_S_OK;
}

static int set_signal(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    if (length == 0) /* a RESET: no signal heard */
        return ASM_S_OK;
    if (data[0] == 0)
        return ASM_S_VALUE_ERROR; /* signals are numbered 1..255 */
    o->value[0] = data[0];
    asm_program_signal(asm_module_of(node), data[0]);
    return ASM_S_OK;
}

static void heard(struct asm_node *node, uint8_t source, const struct asm_message *p)
{
    struct asm_module *m = asm_module_of(node);
    /* every module registers the same objects in the same order: gait.state has the same ID on each */
    if (p->class_id == ASM_C_GAIT_STATE && p->object_id == m->gait.state.id && p->length == 2)
        asm_program_neighbour(m, source, asm_get_u16(p->data));
}

/* -- registration ------------------------------------------------------------------------------------------------ */

/* Every gait object, in the order of registration (the Python module's: object IDs match), as data: one table
 * rather than a page of assignments. */
struct spec {
    const char *name;
    const uint8_t *descriptor;
    asm_set_fn set;
    uint16_t object, value; /* offsets in struct asm_gait; value NONE: no value (a service) */
    uint16_t length, capacity, refuses;
    uint8_t class_id, kind, descriptor_length, flags, publish;
};
#define AT(field) (uint16_t) offsetof(struct asm_gait, field)
#define NONE 0xFFFFu
#define RO ASM_F_READ_ONLY
static const uint8_t HOLD[] = {'G', 'T', 1, 1, 0, 0, 0, 0, 0, 0, 0, 0x80, 0x3F, 0}; /* hold 0 degrees */
static const struct spec SPECS[] = {
    {"gait.table", D_TABLE, set_table, AT(table), AT(table_v), sizeof HOLD, ASM_TABLE_BYTES, ASM_WRITES, ASM_C_GAIT_TABLE,
     ASM_ATTRIBUTE, sizeof D_TABLE, 0, 0},
    {"gait.checksum", D_CHECKSUM, NULL, AT(checksum), AT(checksum_v), 4, 4, 0, ASM_C_GAIT_CHECKSUM, ASM_ATTRIBUTE, sizeof D_CHECKSUM, RO, 0},
    {"gait.phase", D_PHASE, set_phase, AT(phase), AT(phase_v), 4, 4, 0, ASM_C_GAIT_PHASE, ASM_ATTRIBUTE, sizeof D_PHASE, 0, 0},
    {"gait.service", D_SERVICE, NULL, AT(service), NONE, 0, 0, (1u << ASM_START) | (1u << ASM_RESUME), ASM_C_GAIT_SERVICE,
     ASM_SERVICE, sizeof D_SERVICE, 0, 0},
    /* an event: a GET waits for a firing; published once a second (it fires at every tick) */
    {"gait.tick", D_TICK, NULL, AT(tick), AT(tick_v), 8, 8, 0, ASM_C_GAIT_TICK, ASM_EVENT, sizeof D_TICK, RO | ASM_F_SYNC_GET,
     ASM_PUB_RATE},
    {"gait.staged", D_STAGED, set_staged, AT(staged), AT(staged_v), 0, ASM_STAGED_BYTES, ASM_WRITES, ASM_C_GAIT_STAGED,
     ASM_ATTRIBUTE, sizeof D_STAGED, 0, 0},
    {"gait.staged_checksum", D_STAGED_CHECKSUM, NULL, AT(staged_checksum), AT(staged_checksum_v), 4, 4, 0,
     ASM_C_GAIT_STAGED_CHECKSUM, ASM_ATTRIBUTE, sizeof D_STAGED_CHECKSUM, RO, 0},
    {"gait.activate", D_ACTIVATE, set_activate, AT(activate), AT(activate_v), 4, 4, ASM_WRITES, ASM_C_GAIT_ACTIVATE,
     ASM_ATTRIBUTE, sizeof D_ACTIVATE, 0, 0},
    {"gait.lease", D_LEASE, set_lease, AT(lease), AT(lease_v), 0, sizeof(((struct asm_gait *)0)->lease_v), 0,
     ASM_C_GAIT_LEASE, ASM_ATTRIBUTE, sizeof D_LEASE, 0, 0},
    {"gait.direction", D_DIRECTION, set_direction, AT(direction), AT(direction_v), 1, 1, 0, ASM_C_GAIT_DIRECTION, ASM_ATTRIBUTE,
     sizeof D_DIRECTION, 0, 0},
    {"gait.state", D_STATE, NULL, AT(state), AT(state_v), 2, 2, 0, ASM_C_GAIT_STATE, ASM_ATTRIBUTE, sizeof D_STATE, RO, ASM_PUB_EVERY_SET},
    {"gait.switch", D_SWITCH, set_switch, AT(switch_), AT(switch_v), 6, 6, ASM_WRITES, ASM_C_GAIT_SWITCH, ASM_ATTRIBUTE,
     sizeof D_SWITCH, 0, 0},
    {"gait.cycle", D_CYCLE, NULL, AT(cycle), AT(cycle_v), 4, 4, 0, ASM_C_GAIT_CYCLE, ASM_ATTRIBUTE, sizeof D_CYCLE, RO, 0},
    {"gait.mode", D_MODE, NULL, AT(mode), AT(mode_v), 1, 1, 0, ASM_C_GAIT_MODE, ASM_ATTRIBUTE, sizeof D_MODE, RO, ASM_PUB_EVERY_SET},
    {"gait.done", D_DONE, NULL, AT(done), AT(done_v), 1, 1, 0, ASM_C_GAIT_DONE, ASM_EVENT, sizeof D_DONE, RO | ASM_F_SYNC_GET,
     ASM_PUB_EVERY_SET},
    {"gait.signal", D_SIGNAL, set_signal, AT(signal), AT(signal_v), 1, 1, 0, ASM_C_GAIT_SIGNAL, ASM_ATTRIBUTE, sizeof D_SIGNAL, 0, 0},
};
static const uint8_t PARTS[] = {0, 5, 9, sizeof SPECS / sizeof SPECS[0]};

void asm_gait_register(struct asm_module *m, int part)
{
    struct asm_gait *g = &m->gait;
    if (part == 0) {
        g->run.last_ms = m->node.now_ms;
        g->run.now_us = (int64_t)m->node.now_ms * 1000;
        load_table(m, HOLD, sizeof HOLD);
        g->staged_checksum_v = asm_crc32(g->staged_v, 0);
        g->direction_v = 1;
        memcpy(g->switch_v, SWITCH_INITIAL, sizeof SWITCH_INITIAL);
        m->node.on_publication = heard;
    }
    for (uint8_t k = PARTS[part]; k < PARTS[part + 1]; k++) {
        const struct spec *s = &SPECS[k];
        struct asm_object *o = (struct asm_object *)(void *)((uint8_t *)g + s->object);
        asm_object_init(o, s->name, s->class_id, s->kind, s->descriptor, s->descriptor_length,
                        s->value == NONE ? NULL : (uint8_t *)g + s->value, s->length, s->capacity);
        o->set = s->set;
        o->estop_refuses = s->refuses;
        o->flags = s->flags;
        o->publication.mode = s->publish;
        asm_node_register(&m->node, o);
    }
    if (part == 0) {
        g->service.control = control;
        g->tick.publication.refresh_ms = 1000;
    } else if (part == 1) {
        lease_free(g);
    } else
        g->done.valid = 0; /* an event: nothing fired yet */
}
