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
#define ASM_CAN_TIMEOUT_MS 1000u /* a partial message without a fragment for this long is discarded */

enum asm_frame_type { ASM_SINGLE = 0, ASM_FIRST = 1, ASM_MIDDLE = 2, ASM_LAST = 3 };
enum asm_dest_kind { ASM_DEST_NODE = 0, ASM_DEST_GROUP = 1, ASM_DEST_BROADCAST = 2, ASM_DEST_SYSTEM = 3 };

struct asm_can_id {
    uint8_t priority;  /* 0..7 */
    uint8_t dest_kind; /* enum asm_dest_kind */
    uint8_t dest;
    uint8_t source;
    uint8_t frame;     /* enum asm_frame_type */
    uint8_t counter;   /* 0..63 */
};

/* Priorities (identifier bits 28-26) of section 7: lower wins arbitration. */
#define ASM_PRIORITY_ESTOP 0u
#define ASM_PRIORITY_REPLY 2u
#define ASM_PRIORITY_REQUEST 3u
#define ASM_PRIORITY_PUBLICATION 4u
#define ASM_PRIORITY_BULK 5u /* every frame of a message of several frames: a long transfer never delays a short one */
#define ASM_PRIORITY_HEARTBEAT 6u
#define ASM_PRIORITY_BULK_PUBLICATION 7u /* every frame of a publication of several frames: modules filter them out */

/* System frames (destination kind 3): the code in the destination field. */
enum asm_system { ASM_SYSTEM_ESTOP = 0, ASM_SYSTEM_HEARTBEAT = 1, ASM_SYSTEM_LEAVE = 2 };

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
