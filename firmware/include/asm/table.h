/* A module's gait table (docs/protocol.md section 9): version 1 (one periodic automaton) and version 2 (a program
 * of modes, a sequence, event-ended and one-shot states), parsed into fixed arrays and checked as the Python module
 * runtime checks them: same bytes accepted, same bytes refused. */
#ifndef ASM_TABLE_H
#define ASM_TABLE_H

#include <stddef.h>
#include <stdint.h>

#ifndef ASM_MAX_STATES
#define ASM_MAX_STATES 64 /* what this module holds, over all modes; the protocol allows up to 1024 */
#endif
#include "asm/profile.h" /* the module profile's numbers (ASM_PROTOCOL_MAX_STATES, ASM_MAX_MODES, ASM_MAX_SEQUENCE,
                           * ASM_MIN_DURATION, enum asm_event, the class IDs): generated from contract/module.toml */

struct asm_state { /* 20 bytes: floats, then the small fields */
    float target;        /* degrees */
    float duration;      /* seconds; with an event its timeout, 0: none */
    float value;         /* tolerance (at goal) or threshold (torque) */
    uint16_t watch;      /* the neighbour's state, or the signal number */
    uint8_t linear;      /* 0 step, 1 linear */
    uint8_t event;       /* enum asm_event */
    uint8_t stop_on_timeout;
    int8_t neighbour;    /* relative module ID (neighbour) */
    uint8_t emit;        /* signal broadcast on entry, 0: none */
};

struct asm_mode {
    float phase;
    int8_t direction;
    uint8_t one_shot;
    uint16_t first; /* index of its first state in asm_program.states */
    uint16_t count;
};

struct asm_program {
    uint8_t version;
    uint8_t modes_n, sequence_n;
    uint16_t states_n;
    struct asm_mode modes[ASM_MAX_MODES];
    struct { uint8_t mode; uint16_t cycles; } sequence[ASM_MAX_SEQUENCE];
    struct asm_state states[ASM_MAX_STATES];
};

/* ASM_OK; ASM_E_FORMAT for a malformed table; ASM_E_TOO_LARGE for a valid one with more states than
 * ASM_MAX_STATES (the module's declared limit). ``limits`` (min, max degrees) bounds every target. ``program``
 * NULL: only check (a staged table is kept as bytes and parsed when it is activated). */
int asm_table_parse(const uint8_t *data, size_t length, const float limits[2], struct asm_program *program);

#endif
