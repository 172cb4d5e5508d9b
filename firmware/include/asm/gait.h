/* A module's gait (docs/protocol.md section 9): the table, its checksum, phase, direction and state, the control
 * tick, the program that turns the table into joint.goal (src/program.c), and a deployment's staging, activation
 * and lease.
 *
 * The program is the Python module's (asm_module/gait_service.py), rule for rule: a periodic time-driven mode by
 * phase time (tau = phi * T + d * t), any other mode stepped state by state at each tick, ended by time or by an
 * event — contact made or lost, at goal, torque, a neighbour's state, a broadcast signal — with cycles, a sequence,
 * switches at cycle boundaries, one-shot modes, the 0.5 s blend at a switch and the 1 s ramp at a start. Times are
 * integer microseconds (no double precision on a Cortex-M4, and no drift over days); angles single precision.
 *
 * Declared limits, refused with VALUE_ERROR beyond (never a crash): ASM_MAX_STATES states over all modes,
 * ASM_MAX_NEIGHBOURS distinct neighbours and ASM_MAX_SIGNALS distinct signals waited on, and a table of at most
 * ASM_TABLE_BYTES bytes (TOO_LARGE, from the node, beyond). */
#ifndef ASM_GAIT_H
#define ASM_GAIT_H

#include <stdint.h>

#include "asm/node.h"
#include "asm/table.h"

#ifndef ASM_MAX_NEIGHBOURS
#define ASM_MAX_NEIGHBOURS 4 /* distinct neighbours a program's states wait on */
#endif
#ifndef ASM_MAX_SIGNALS
#define ASM_MAX_SIGNALS 8 /* distinct broadcast signals a program's states wait on */
#endif
#ifndef ASM_TABLE_BYTES
#define ASM_TABLE_BYTES (5u + 9u * ASM_MAX_STATES) /* a version-1 table of ASM_MAX_STATES states */
#endif
#define ASM_STAGED_BYTES (12u + ASM_TABLE_BYTES)
#define ASM_LEASE_HOLDER 32u /* bytes of a lease holder's name kept */

/* What was heard from a neighbour (its gait.state) or of a broadcast signal, and when (the module's clock). */
struct asm_heard {
    int64_t at_us;
    uint16_t value;  /* the neighbour's state */
    int16_t key;     /* the neighbour's offset, or the signal's number; 0: a free slot */
    uint8_t heard;
};

/* The program while gait.service runs (the fields of asm_py's ModuleGait). */
struct asm_run {
    int64_t now_us, entered_us, boundary_us, last_tick_us, tau_us, period_us, blend_since_us, paused_us, after_us;
    uint32_t last_ms;
    int32_t cycles_left;
    float blend, reference, base_phase;
    uint16_t index;
    uint8_t mode, sequence_at, timed, finished, saw_free, saw_touch, switch_pending, switch_mode, watch_changed;
    int8_t drive, base_direction, switch_direction;
};

struct asm_gait {
    struct asm_object table, checksum, phase, service, tick, staged, staged_checksum, activate, lease, direction, state,
        switch_, cycle, mode, done, signal;
    uint8_t table_v[ASM_TABLE_BYTES], staged_v[ASM_STAGED_BYTES], lease_v[1 + ASM_LEASE_HOLDER + 8], switch_v[6];
    uint32_t checksum_v, staged_checksum_v, activate_v, lease_token, lease_expires_ms, cycle_v;
    float phase_v;
    int8_t direction_v;
    uint8_t mode_v, done_v, signal_v;
    uint16_t state_v;
    uint64_t tick_v; /* gait.tick: float64 bits */
    struct asm_program program; /* what runs (a staged table stays bytes until activated) */
    struct asm_run run;
    struct asm_heard neighbours[ASM_MAX_NEIGHBOURS], signals[ASM_MAX_SIGNALS];
    float ramp_from;
    uint32_t ramp_start_ms;
    uint8_t staged_ok, lease_held;
};

struct asm_module;
/* Register the gait's objects on the module's node (after the joint's: the IDs of docs/protocol.md's example). */
void asm_gait_register(struct asm_module *m, int part);
/* One control tick at ``now_ms``: the tick event, then the automaton's next goal. */
void asm_gait_tick(struct asm_module *m, uint32_t now_ms);
/* The e-stop latched: the gait stops where it is. */
void asm_gait_halt(struct asm_module *m);
/* Forget what was staged (an e-stop: no deployment begun before it may start after it). */
void asm_gait_discard_staged(struct asm_module *m);

/* src/program.c: the automaton. */
int64_t asm_us_of(float seconds); /* microseconds, rounded, clamped to +-2e9 s */
void asm_program_start(struct asm_module *m, uint32_t now_ms);
void asm_program_tick(struct asm_module *m, uint32_t now_ms);
void asm_program_suspend(struct asm_module *m);
void asm_program_resume(struct asm_module *m, uint32_t now_ms);
/* The program in g->program was replaced: what it waits on starts afresh (what was heard of the same neighbours and
 * signals stays: they publish only on a change). */
void asm_program_loaded(struct asm_module *m);
/* VALUE_ERROR when table ``data`` (already parsed) waits on more neighbours or signals than this module keeps, or
 * on a neighbour outside IDs 1..254; else OK. */
int asm_program_fits(const struct asm_module *m, const uint8_t *data, size_t length);
/* A publication of gait.state by node ``source``; a broadcast signal heard (a SET of gait.signal, or emitted). */
void asm_program_neighbour(struct asm_module *m, uint8_t source, uint16_t state);
void asm_program_signal(struct asm_module *m, uint8_t number);
/* The node IDs whose gait.state publications the program waits on (what a port's acceptance filter must pass);
 * returns how many, at most ASM_MAX_NEIGHBOURS. */
uint8_t asm_program_watched(const struct asm_module *m, uint8_t ids[ASM_MAX_NEIGHBOURS]);

#endif
