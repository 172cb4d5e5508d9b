/* ASM over CAN (docs/protocol.md section 7): the 29-bit identifier, fragmentation and bounded reassembly.
 *
 * The reassembler is a fixed array of ASM_CAN_PARTIALS slots of ASM_CAN_MAX_MESSAGE + 64 bytes each: a module sets
 * ASM_CAN_PARTIALS and ASM_CAN_MAX_MESSAGE to what its RAM allows (the Python side defaults to 64; a module talks to few peers at once). */
#ifndef ASM_CAN_H
#define ASM_CAN_H

#include <stddef.h>
#include <stdint.h>

#include "asm/wire.h"

#ifndef ASM_CAN_PARTIALS
#define ASM_CAN_PARTIALS 4
#endif
#ifndef ASM_CAN_MAX_MESSAGE
#define ASM_CAN_MAX_MESSAGE ASM_MAX_MESSAGE /* the longest message a slot takes; a longer one is dropped */
#endif
/* ASM_CAN_TIMEOUT_MS (a partial message's life), enum asm_frame_type, enum asm_dest_kind, enum asm_system, the
 * identifier's fields (ASM_CAN_*_SHIFT, ASM_CAN_*_MASK) and the priorities (ASM_PRIORITY_*) are in the generated
 * asm/contract.h, included by asm/wire.h. */

struct asm_can_id {
    uint8_t priority;  /* 0..7 */
    uint8_t dest_kind; /* enum asm_dest_kind */
    uint8_t dest;
    uint8_t source;
    uint8_t frame;     /* enum asm_frame_type */
    uint8_t counter;   /* 0..63 */
};

uint32_t asm_can_pack(const struct asm_can_id *id);
/* How many frames a message of ``length`` bytes takes, and the priority they go out at. */
size_t asm_fragment_count(size_t length, int fd);
uint8_t asm_frame_priority(uint8_t priority, size_t frames);
void asm_can_unpack(uint32_t arbitration_id, struct asm_can_id *id);

/* The frames of one message, one at a time (no copy of the message: it must outlive the fragmenter). */
struct asm_fragmenter {
    const uint8_t *message;
    size_t length;
    size_t offset;
    uint8_t frame_size; /* 8 classic, 64 FD */
    uint8_t counter;
    uint8_t started;
    uint8_t done;
};

/* ASM_OK, or ASM_E_TOO_LARGE for a message over 65,535 bytes. */
int asm_fragment_begin(struct asm_fragmenter *f, const uint8_t *message, size_t length, int fd);
/* The next frame: 1 and its type, counter and data (``data`` holds 64 bytes; ``*dlc`` its length), 0 when done. */
int asm_fragment_next(struct asm_fragmenter *f, uint8_t *frame, uint8_t *counter, uint8_t *data, uint8_t *dlc);

struct asm_partial {
    uint8_t used;
    uint8_t source, dest_kind, dest;
    uint8_t counter;
    uint16_t length, crc;
    size_t have;
    uint32_t touched_ms;
    uint8_t last[64];
    uint8_t last_length;
    uint8_t data[ASM_CAN_MAX_MESSAGE + 64];
};

struct asm_reassembler {
    struct asm_partial slots[ASM_CAN_PARTIALS];
    uint32_t dropped; /* fragments and messages refused: gaps, orphans, CRC, too long, evicted, expired */
};

void asm_reassembler_init(struct asm_reassembler *r);
/* Take one frame; 1 with ``*message``/``*length`` when it completes a message (valid until the next call), else 0.
 * A SINGLE frame is its own message. */
int asm_reassemble(struct asm_reassembler *r, const struct asm_can_id *id, const uint8_t *data, uint8_t dlc,
                   uint32_t now_ms, const uint8_t **message, size_t *length);
/* Discard partial messages older than ASM_CAN_TIMEOUT_MS. */
void asm_reassembler_expire(struct asm_reassembler *r, uint32_t now_ms);

#endif
