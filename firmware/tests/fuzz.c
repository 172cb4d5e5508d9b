/* Hostile input for the parsers: random and mutated frames into the reassembler, random and mutated bytes into the
 * message decoder and the gait-table parser. Run under AddressSanitizer and UndefinedBehaviorSanitizer: no crash,
 * no report, and the reassembler still completes a well-formed message afterwards.
 *
 *   fuzz ITERATIONS SEED */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asm/can.h"
#include "asm/table.h"
#include "asm/wire.h"

static uint64_t state;

static uint32_t next(void)
{
    state ^= state << 13;
    state ^= state >> 7;
    state ^= state << 17;
    return (uint32_t)(state >> 16);
}

static struct asm_reassembler reassembler;
static struct asm_program program;

int main(int argc, char **argv)
{
    unsigned long iterations = argc > 1 ? strtoul(argv[1], NULL, 10) : 100000;
    state = argc > 2 ? strtoull(argv[2], NULL, 10) | 1u : 88172645463325252ull;
    static const float limits[2] = {-90.0f, 90.0f};
    static uint8_t message[ASM_MAX_MESSAGE], buffer[ASM_MAX_MESSAGE + 16];
    asm_reassembler_init(&reassembler);
    unsigned long completed = 0, parsed = 0;
    uint32_t now = 0;
    for (unsigned long k = 0; k < iterations; k++) {
        now += next() % 50;
        /* a frame: random identifier and data, or a piece of a real fragmentation with one thing changed */
        struct asm_can_id id;
        asm_can_unpack(next() & 0x1FFFFFFFu, &id);
        id.source = (uint8_t)(1 + next() % 4); /* few keys, so partial messages meet */
        uint8_t data[64], dlc = (uint8_t)(next() % 65);
        for (int b = 0; b < dlc; b++)
            data[b] = (uint8_t)next();
        if (next() % 4 == 0 && dlc >= 4) { /* a first frame announcing a plausible length */
            id.frame = ASM_FIRST;
            id.counter = 0;
            uint16_t length = (uint16_t)(next() % (ASM_MAX_MESSAGE + 100));
            data[0] = (uint8_t)length;
            data[1] = (uint8_t)(length >> 8);
        }
        const uint8_t *out;
        size_t length;
        completed += (unsigned long)asm_reassemble(&reassembler, &id, data, dlc, now, &out, &length);
        if (next() % 64 == 0)
            asm_reassembler_expire(&reassembler, now);
        /* bytes into the decoder and the table parser: random, or a table with a byte changed */
        size_t n = next() % 200;
        for (size_t b = 0; b < n; b++)
            buffer[b] = (uint8_t)next();
        if (n >= 5 && next() % 2) {
            buffer[0] = 'G';
            buffer[1] = 'T';
            buffer[2] = (uint8_t)(1 + next() % 2);
        }
        struct asm_message m;
        if (asm_decode(buffer, n, &m) == ASM_OK) {
            long written = asm_encode(&m, message, sizeof message);
            if (written != (long)n || memcmp(message, buffer, n) != 0) {
                fprintf(stderr, "decode/encode does not round-trip at iteration %lu\n", k);
                return 1;
            }
        }
        parsed += asm_table_parse(buffer, n, limits, &program) == ASM_OK;
    }
    /* afterwards a well-formed message still goes through */
    for (size_t b = 0; b < 300; b++)
        message[b] = (uint8_t)(b * 7);
    struct asm_fragmenter f;
    asm_fragment_begin(&f, message, 300, 0);
    uint8_t frame, counter, data[64], dlc;
    const uint8_t *out = NULL;
    size_t length = 0;
    int done = 0;
    while (asm_fragment_next(&f, &frame, &counter, data, &dlc)) {
        struct asm_can_id id = {5, ASM_DEST_NODE, 9, 200, frame, counter};
        done = asm_reassemble(&reassembler, &id, data, dlc, now, &out, &length);
    }
    if (!done || length != 300 || memcmp(out, message, 300) != 0) {
        fprintf(stderr, "the reassembler no longer completes a well-formed message\n");
        return 1;
    }
    printf("fuzzed %lu inputs: %lu messages completed, %lu tables parsed, %lu dropped; still answers\n", iterations,
           completed, parsed, (unsigned long)reassembler.dropped);
    return 0;
}
