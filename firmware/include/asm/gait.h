/* A module's gait (docs/protocol.md section 9): the table, its checksum, phase, direction and state, the control
 * tick, the periodic phase automaton that turns the table into joint.goal, and a deployment's staging, activation
 * and lease. The automaton is the Python module's rule, step for step: phase time tau = phi * T + d * t from an
 * anchor, the reference of the state tau falls in, and a 1 s ramp from the goal held at the start. Single
 * precision throughout (a Cortex-M4 has no double-precision unit): it agrees with the Python module's float64
 * within microseconds of phase time, and on which state a tick falls in except at a tie with a state boundary.
 *
 * This slice runs time-driven periodic tables (every table version 1 can say); a program with event-ended or
 * one-shot states, several modes or a sequence is refused with VALUE_ERROR — its limit, declared, not a crash. */
#ifndef ASM_GAIT_H
#define ASM_GAIT_H

#include <stdint.h>

#include "asm/node.h"
#include "asm/table.h"

#define ASM_TABLE_BYTES (5u + 9u * ASM_MAX_STATES) /* a version-1 table of ASM_MAX_STATES states */
#define ASM_STAGED_BYTES (12u + ASM_TABLE_BYTES)
#define ASM_LEASE_HOLDER 32u /* bytes of a lease holder's name kept */

struct asm_gait {
    struct asm_object table, checksum, phase, service, tick, staged, staged_checksum, activate, lease, direction, state;
    uint8_t table_v[ASM_TABLE_BYTES], staged_v[ASM_STAGED_BYTES], lease_v[1 + ASM_LEASE_HOLDER + 8];
    uint32_t checksum_v, staged_checksum_v, activate_v, lease_token, lease_expires_ms;
    float phase_v;
    int8_t direction_v;
    uint16_t state_v;
    double tick_v;
    struct asm_program program, staged_program; /* what runs; what is staged, checked */
    /* Phase time in float seconds within one period; wall time in integer milliseconds since an anchor, so a
     * module running for days loses no precision (the anchor moves on every REANCHOR_MS). */
    float period, tau, tau0, ramp_from;
    uint32_t t0_ms, last_tick_ms, ramp_start_ms;
    int8_t heading;
    uint8_t staged_ok, lease_held;
};

struct asm_module;
/* Register the gait's objects on the module's node (after the joint's: the IDs of docs/protocol.md's example). */
void asm_gait_register(struct asm_module *m, int part);
/* One control tick at ``now_ms``: the tick event, then the automaton's next goal. */
void asm_gait_tick(struct asm_module *m, uint32_t now_ms);
/* The e-stop latched: the gait stops where it is. */
void asm_gait_halt(struct asm_module *m);

#endif
