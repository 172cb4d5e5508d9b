/* The program a module runs (docs/protocol.md section 9, "How a module runs a program"): asm_py's ModuleGait in C,
 * function for function, so a C module and a Python module decide the same at the same tick. See asm/gait.h. */
#include <math.h>
#include <string.h>

#include "asm/module.h"

#define RAMP_MS 1000u
#define BLEND_SECONDS 0.5f
#define NEVER INT64_MAX
enum { FINISHED = 1, TIMED_OUT = 2 };

/* Conversions between float seconds and int64 microseconds through int32 parts only: the Cortex-M4's FPU converts
 * to and from int32; int64 conversions would pull in libgcc's double-precision code (2 KiB of flash). */
int64_t asm_us_of(float seconds)
{
    seconds = seconds < -2e9f ? -2e9f : seconds > 2e9f ? 2e9f : seconds; /* 63 years either way */
    int32_t whole = (int32_t)seconds;
    float rest = (seconds - (float)whole) * 1e6f;
    return (int64_t)whole * 1000000 + (int32_t)(rest + (rest < 0.0f ? -0.5f : 0.5f));
}

static float seconds_of(int64_t us)
{
    if (us > -2000000000 && us < 2000000000)
        return (float)(int32_t)us * 1e-6f;
    return (float)(int32_t)(us >> 20) * (1048576 * 1e-6f) + (float)(int32_t)(us & 0xFFFFF) * 1e-6f;
}

/* floor(v / period) for v >= 0, and v modulo ``period`` in [0, period) for any v, by subtracting doubled periods:
 * no 64-bit division (libgcc's is 600 bytes of a Cortex-M4's flash), and a clock that jumped by an hour over a
 * microsecond's period costs 64² steps, not 10⁹. */
static int64_t quotient(int64_t v, int64_t period, int64_t *rest)
{
    int64_t q = 0;
    while (v >= period) {
        int64_t p = period, k = 1;
        while (p <= v - p)
            p <<= 1, k <<= 1;
        v -= p;
        q += k;
    }
    *rest = v;
    return q;
}

static int64_t wrap(int64_t v, int64_t period)
{
    int64_t rest;
    if (v < 0)
        return period - 1 - wrap(-(v + 1), period);
    quotient(v, period, &rest);
    return rest;
}

/* A state's duration in microseconds: at least 1, so a period is never 0. */
static int64_t duration_us(const struct asm_state *s)
{
    int64_t us = asm_us_of(s->duration);
    return us > 0 ? us : 1;
}

static const struct asm_mode *mode_of(const struct asm_gait *g) { return &g->program.modes[g->run.mode]; }
static const struct asm_state *state_of(const struct asm_gait *g, uint16_t k)
{
    return &g->program.states[mode_of(g)->first + k];
}
static uint16_t first_mode(const struct asm_program *p) { return p->sequence_n ? p->sequence[0].mode : 0; }
/* The sequence has a step after the current one: a boundary counts down its cycles. */
static int sequenced(const struct asm_gait *g) { return g->run.sequence_at + 1 < g->program.sequence_n; }

/* The state of the current (timed) mode phase time ``tau`` falls in — bisect_right over the states' starts — and
 * its start. */
static uint16_t state_at(const struct asm_gait *g, int64_t tau, int64_t *start)
{
    uint16_t index = 0;
    int64_t at = 0;
    *start = 0;
    for (uint16_t k = 0; k < mode_of(g)->count; at += duration_us(state_of(g, k)), k++)
        if (at <= tau) {
            index = k;
            *start = at;
        }
    return index;
}

/* Periodic and time-driven: run by phase time. */
static int timed(const struct asm_program *p, const struct asm_mode *mode)
{
    if (mode->one_shot)
        return 0;
    for (uint16_t k = 0; k < mode->count; k++)
        if (p->states[mode->first + k].event != ASM_EV_NONE)
            return 0;
    return 1;
}

static int64_t clock_us(struct asm_gait *g, uint32_t now_ms);
static int64_t min64(int64_t a, int64_t b) { return a < b ? a : b; }

/* -- what was heard ---------------------------------------------------------------------------------------------- */

static struct asm_heard *slot(struct asm_heard *table, uint8_t size, int16_t key)
{
    for (uint8_t k = 0; k < size; k++)
        if (table[k].key == key)
            return &table[k];
    return NULL;
}

void asm_program_neighbour(struct asm_module *m, uint8_t source, uint16_t state)
{
    struct asm_heard *h = slot(m->gait.neighbours, ASM_MAX_NEIGHBOURS, (int16_t)(source - m->node.node_id));
    if (h != NULL && source != m->node.node_id)
        *h = (struct asm_heard){clock_us(&m->gait, m->node.now_ms), state, h->key, 1};
}

void asm_program_signal(struct asm_module *m, uint8_t number)
{
    struct asm_heard *h = slot(m->gait.signals, ASM_MAX_SIGNALS, number);
    if (h != NULL && number != 0)
        *h = (struct asm_heard){clock_us(&m->gait, m->node.now_ms), 0, number, 1};
}

/* Collect the distinct keys the states of a parsed table wait on: neighbours (offsets) or signals (numbers). */
static int keys(const uint8_t *data, size_t length, uint8_t event, int16_t *out, uint8_t size)
{
    uint8_t found = 0;
    if (length < 5 || data[2] != 2)
        return 0;
    size_t offset = 5u + 3u * data[4];
    for (uint8_t mode = 0; mode < data[3]; mode++) {
        uint16_t n = asm_get_u16(data + offset + 6);
        offset += 8;
        for (uint16_t k = 0; k < n; k++, offset += 19) {
            const uint8_t *s = data + offset;
            if (s[9] != event)
                continue;
            int16_t key = event == ASM_EV_NEIGHBOUR ? (int16_t)(int8_t)s[15] : (int16_t)asm_get_u16(s + 16);
            uint8_t j = 0;
            while (j < found && out[j] != key)
                j++;
            if (j == found) {
                if (found == size)
                    return -1;
                out[found++] = key;
            }
        }
    }
    return found;
}

int asm_program_fits(const struct asm_module *m, const uint8_t *data, size_t length)
{
    int16_t offsets[ASM_MAX_NEIGHBOURS], numbers[ASM_MAX_SIGNALS];
    int n = keys(data, length, ASM_EV_NEIGHBOUR, offsets, ASM_MAX_NEIGHBOURS);
    if (n < 0 || keys(data, length, ASM_EV_SIGNAL, numbers, ASM_MAX_SIGNALS) < 0)
        return ASM_S_VALUE_ERROR;
    for (int k = 0; k < n; k++)
        if (m->node.node_id + offsets[k] < 1 || m->node.node_id + offsets[k] > 254)
            return ASM_S_VALUE_ERROR;
    return ASM_S_OK;
}

/* The keys of the program now in force, keeping what was heard for the keys it shares with the one before. */
static void rekey(struct asm_heard *table, uint8_t size, const int16_t *wanted, int count)
{
    struct asm_heard kept[ASM_MAX_SIGNALS > ASM_MAX_NEIGHBOURS ? ASM_MAX_SIGNALS : ASM_MAX_NEIGHBOURS] = {{0}};
    for (int k = 0; k < count; k++) {
        struct asm_heard *old = slot(table, size, wanted[k]);
        kept[k] = old != NULL ? *old : (struct asm_heard){0, 0, wanted[k], 0};
    }
    memcpy(table, kept, size * sizeof *table);
}

void asm_program_loaded(struct asm_module *m)
{
    struct asm_gait *g = &m->gait;
    int16_t offsets[ASM_MAX_NEIGHBOURS] = {0}, numbers[ASM_MAX_SIGNALS] = {0};
    int n = keys(g->table_v, g->table.length, ASM_EV_NEIGHBOUR, offsets, ASM_MAX_NEIGHBOURS);
    rekey(g->neighbours, ASM_MAX_NEIGHBOURS, offsets, n < 0 ? 0 : n);
    n = keys(g->table_v, g->table.length, ASM_EV_SIGNAL, numbers, ASM_MAX_SIGNALS);
    rekey(g->signals, ASM_MAX_SIGNALS, numbers, n < 0 ? 0 : n);
    g->run.watch_changed = 1;
}

uint8_t asm_program_watched(const struct asm_module *m, uint8_t ids[ASM_MAX_NEIGHBOURS])
{
    uint8_t n = 0;
    for (uint8_t k = 0; k < ASM_MAX_NEIGHBOURS; k++)
        if (m->gait.neighbours[k].key != 0)
            ids[n++] = (uint8_t)(m->node.node_id + m->gait.neighbours[k].key);
    return n;
}

/* -- the reference ----------------------------------------------------------------------------------------------- */

static float reference(const struct asm_gait *g, int64_t now)
{
    const struct asm_run *r = &g->run;
    uint16_t n = mode_of(g)->count;
    const struct asm_state *s = state_of(g, r->index);
    float frac;
    uint16_t previous;
    if (r->timed) { /* from the previous state of the table, by phase time */
        int64_t start;
        state_at(g, r->tau_us, &start);
        previous = (uint16_t)((r->index + n - 1) % n);
        frac = seconds_of(r->tau_us - start) / s->duration;
    } else {
        if (!s->linear || s->duration == 0.0f)
            return s->target;
        previous = (uint16_t)((r->index - g->direction_v + n) % n);
        frac = seconds_of(now - r->entered_us) / s->duration;
        frac = frac < 0.0f ? 0.0f : frac > 1.0f ? 1.0f : frac;
    }
    if (!s->linear)
        return s->target;
    float from = state_of(g, previous)->target;
    return from + frac * (s->target - from);
}

static void output(struct asm_module *m, int64_t now)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    float value = reference(g, now);
    if (r->blend != 0.0f) {
        float left = 1.0f - seconds_of(now - r->blend_since_us) / BLEND_SECONDS;
        if (left <= 0.0f)
            r->blend = 0.0f;
        else
            value += r->blend * left;
    }
    r->reference = value;
    uint32_t since = m->node.now_ms - g->ramp_start_ms; /* the 1 s ramp from the goal held at the start */
    float ramp = since >= RAMP_MS ? 1.0f : (float)since / (float)RAMP_MS;
    asm_module_set_goal(m, g->ramp_from + ramp * (value - g->ramp_from));
}

/* -- states, modes, switches ------------------------------------------------------------------------------------- */

static void emit(struct asm_module *m, uint8_t number)
{
    uint8_t message[5] = {(ASM_VERSION << 6) | (ASM_REQUEST << 4) | ASM_SET, 0, 0x2F, 0, number};
    asm_program_signal(m, number); /* a group message does not come back to its sender */
    asm_node_send(&m->node, ASM_DEST_BROADCAST, 0, message, sizeof message, ASM_PRIORITY_REQUEST);
}

static void enter_state(struct asm_module *m, uint16_t index, int64_t at)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    r->index = index;
    r->entered_us = at;
    r->saw_free = !m->contact_v; /* contact made / lost are edges within the state */
    r->saw_touch = m->contact_v != 0;
    if (index != g->state_v || !g->state.valid)
        asm_node_write(&m->node, &g->state, &index, 2);
    if (state_of(g, index)->emit)
        emit(m, state_of(g, index)->emit);
}

static void enter_mode(struct asm_module *m, uint8_t index, int64_t at, float phase, int8_t heading, int blend)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    float old = r->reference;
    r->mode = index;
    if (index != g->mode_v || !g->mode.valid)
        asm_node_write(&m->node, &g->mode, &index, 1);
    g->direction_v = heading;
    uint16_t n = mode_of(g)->count, now_index;
    r->timed = (uint8_t)timed(&g->program, mode_of(g));
    if (r->timed) {
        float period = 0.0f;
        r->period_us = 0;
        for (uint16_t k = 0; k < n; k++) {
            r->period_us += duration_us(state_of(g, k));
            period += state_of(g, k)->duration;
        }
        r->tau_us = asm_us_of(phase * period);
        r->tau_us = r->tau_us < r->period_us ? r->tau_us : r->period_us - 1;
        r->last_tick_us = at;
        r->boundary_us = at + r->period_us;
        int64_t start;
        now_index = state_at(g, r->tau_us, &start);
    } else {
        now_index = (uint16_t)(phase * (float)n);
        now_index = now_index < n ? now_index : (uint16_t)(n - 1);
        r->boundary_us = NEVER;
    }
    enter_state(m, now_index, at);
    r->blend = blend ? old - reference(g, at) : 0.0f;
    r->blend_since_us = at;
}

static void switch_to(struct asm_module *m, uint8_t index, int8_t drive, int64_t at)
{
    struct asm_gait *g = &m->gait;
    const struct asm_mode *mode = &g->program.modes[index];
    float phase = mode->phase;
    int8_t direction = mode->direction;
    if (index == first_mode(&g->program)) { /* the start mode keeps the phase and direction it was started with */
        phase = g->run.base_phase;
        direction = g->run.base_direction;
    }
    g->run.drive = drive;
    enter_mode(m, index, at, phase, (int8_t)(direction * drive), 1);
}

static int switch_due(struct asm_module *m, int64_t at)
{
    struct asm_run *r = &m->gait.run;
    if (!r->switch_pending || at < r->after_us)
        return 0;
    r->switch_pending = 0;
    switch_to(m, r->switch_mode, r->switch_direction, at);
    return 1;
}

static int next_step(struct asm_module *m, int64_t at)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    if (!sequenced(g))
        return 0;
    r->sequence_at++;
    r->cycles_left = g->program.sequence[r->sequence_at].cycles;
    switch_to(m, g->program.sequence[r->sequence_at].mode, r->drive, at);
    return 1;
}

/* A cycle ended at ``at``: count it, and switch if a switch or the sequence says so; 1 if it switched. */
static int cross_boundary(struct asm_module *m, int64_t at)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    uint32_t cycle = g->cycle_v + 1;
    asm_node_write(&m->node, &g->cycle, &cycle, 4);
    if (switch_due(m, at))
        return 1;
    if (sequenced(g) && --r->cycles_left <= 0)
        return next_step(m, at);
    return 0;
}

static void end_run(struct asm_module *m, uint8_t outcome)
{
    m->gait.run.finished = 1;
    asm_node_write(&m->node, &m->gait.done, &outcome, 1);
    asm_gait_halt(m); /* the joint holds its last goal */
}

/* Move to the next state in the direction of travel; 0 when the run ended or the mode changed. */
static int advance(struct asm_module *m, int64_t at)
{
    struct asm_gait *g = &m->gait;
    int32_t n = mode_of(g)->count, index = g->run.index + g->direction_v;
    if (index < 0 || index >= n) {
        if (mode_of(g)->one_shot) {
            if (!switch_due(m, at) && !next_step(m, at))
                end_run(m, FINISHED);
            return 0;
        }
        enter_state(m, (uint16_t)((index + n) % n), at);
        return !cross_boundary(m, at);
    }
    enter_state(m, (uint16_t)index, at);
    return 1;
}

static int happened(struct asm_module *m, const struct asm_state *s, int contact)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    struct asm_heard *h;
    switch (s->event) {
    case ASM_EV_CONTACT: return contact && r->saw_free;
    case ASM_EV_NO_CONTACT: return !contact && r->saw_touch;
    case ASM_EV_AT_GOAL: return fabsf(m->angle_v - s->target) <= s->value;
    case ASM_EV_TORQUE: return fabsf(m->torque_v) >= s->value;
    case ASM_EV_SIGNAL: /* heard since the state began, before this tick */
        h = slot(g->signals, ASM_MAX_SIGNALS, (int16_t)s->watch);
        return h != NULL && h->heard && r->entered_us <= h->at_us && h->at_us < r->now_us;
    default: /* a neighbour's state, counted from the tick after it arrived */
        h = slot(g->neighbours, ASM_MAX_NEIGHBOURS, s->neighbour);
        return h != NULL && h->heard && h->value == s->watch && h->at_us < r->now_us;
    }
}

static void step_states(struct asm_module *m, int64_t now)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    for (int32_t k = 0; k < 4 * mode_of(g)->count + 1; k++) { /* several short states may end within one tick */
        const struct asm_state *s = state_of(g, r->index);
        int contact = m->contact_v != 0;
        r->saw_free |= !contact;
        r->saw_touch |= contact;
        int64_t end;
        if (s->event != ASM_EV_NONE && happened(m, s, contact))
            end = now;
        else if (s->duration > 0.0f && now - r->entered_us >= duration_us(s)) {
            if (s->event != ASM_EV_NONE && s->stop_on_timeout) {
                end_run(m, TIMED_OUT);
                return;
            }
            end = r->entered_us + duration_us(s);
        } else
            return;
        if (!advance(m, end) || r->timed)
            return;
    }
}

static void step_timed(struct asm_module *m, int64_t now)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    while (r->timed && now >= r->boundary_us) {
        /* boundaries that only count a cycle — before a switch is due, before the sequence's next step — are
         * crossed together: a long pause over a short period costs a few steps, not one per boundary */
        int64_t rest, skip = quotient(now - r->boundary_us, r->period_us, &rest);
        if (r->switch_pending)
            skip = r->after_us <= r->boundary_us ? 0 : min64(skip, quotient(r->after_us - r->boundary_us - 1,
                                                                             r->period_us, &rest));
        if (sequenced(g))
            skip = min64(skip, r->cycles_left > 1 ? r->cycles_left - 1 : 0);
        if (skip > 0) {
            uint32_t cycle = g->cycle_v + (uint32_t)skip;
            asm_node_write(&m->node, &g->cycle, &cycle, 4);
            r->boundary_us += skip * r->period_us;
            r->cycles_left -= (int32_t)(sequenced(g) ? skip : 0);
        }
        int64_t boundary = r->boundary_us;
        r->boundary_us += r->period_us;
        if (cross_boundary(m, boundary) && !r->timed) {
            step_states(m, now);
            return;
        }
    }
    /* a direction set directly applies from the previous tick on */
    r->tau_us = wrap(r->tau_us + g->direction_v * (now - r->last_tick_us), r->period_us);
    r->last_tick_us = now;
    int64_t start;
    uint16_t index = state_at(g, r->tau_us, &start);
    if (index != r->index)
        enter_state(m, index, now);
}

/* -- the service ------------------------------------------------------------------------------------------------- */

/* The module's clock in microseconds, extended from the port's wrapping milliseconds (never backwards). */
static int64_t clock_us(struct asm_gait *g, uint32_t now_ms)
{
    if ((int32_t)(now_ms - g->run.last_ms) > 0) {
        g->run.now_us += (int64_t)(now_ms - g->run.last_ms) * 1000;
        g->run.last_ms = now_ms;
    }
    return g->run.now_us;
}

void asm_program_start(struct asm_module *m, uint32_t now_ms)
{
    struct asm_gait *g = &m->gait;
    struct asm_run *r = &g->run;
    int64_t now = clock_us(g, now_ms);
    uint32_t zero = 0;
    r->finished = 0;
    r->switch_pending = 0;
    asm_node_write(&m->node, &g->cycle, &zero, 4);
    r->sequence_at = 0;
    r->cycles_left = g->program.sequence_n ? g->program.sequence[0].cycles : 0;
    r->drive = 1;
    r->base_phase = g->phase_v;
    r->base_direction = g->direction_v;
    g->ramp_from = m->goal_v;
    g->ramp_start_ms = now_ms;
    g->service.started = g->service.running = 1;
    enter_mode(m, (uint8_t)first_mode(&g->program), now, g->phase_v, g->direction_v, 0);
    output(m, now);
}

void asm_program_tick(struct asm_module *m, uint32_t now_ms)
{
    struct asm_gait *g = &m->gait;
    int64_t now = clock_us(g, now_ms);
    if (!g->service.running || m->node.estop || g->run.finished)
        return;
    if (g->run.timed)
        step_timed(m, now);
    else
        step_states(m, now);
    if (!g->run.finished)
        output(m, now);
}

void asm_program_suspend(struct asm_module *m) { m->gait.run.paused_us = m->gait.run.now_us; }

void asm_program_resume(struct asm_module *m, uint32_t now_ms)
{
    struct asm_run *r = &m->gait.run;
    int64_t now = clock_us(&m->gait, now_ms), pause = now - r->paused_us;
    pause = pause > 0 ? pause : 0;
    r->entered_us += pause;
    if (r->boundary_us != NEVER)
        r->boundary_us += pause;
    r->blend_since_us += pause;
    r->last_tick_us = now;
}
