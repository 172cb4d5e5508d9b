/* Hostile input for the parsers: random and mutated frames into the reassembler, random and mutated bytes into the
 * message decoder and the gait-table parser, and random, mutated and well-formed request frames into a module (the
 * node's request server and the module objects); and random programs — every event, one-shot modes, sequences,
 * signals, neighbours, durations from one control tick (20 ms) to hours, and some just below it (refused) — loaded, mutated and run by the module with random
 * sensor readings, neighbours' states, signals and switches arriving. Run under AddressSanitizer and UndefinedBehaviorSanitizer: no
 * crash, no report; afterwards the reassembler still completes a well-formed message and the module still answers
 * a lookup.
 *
 *   fuzz ITERATIONS SEED */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asm/can.h"
#include "asm/module.h"
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
static struct asm_module module;
static unsigned long replies_to_200;
static float joint_angle;

static int sent(void *ctx, uint32_t id, const uint8_t *data, uint8_t dlc)
{
    struct asm_can_id cid;
    (void)ctx;
    (void)data;
    (void)dlc;
    asm_can_unpack(id, &cid);
    replies_to_200 += cid.dest_kind == ASM_DEST_NODE && cid.dest == 200;
    return 0;
}

static void command(void *ctx, float degrees) { (void)ctx; joint_angle = degrees; }
static void relax(void *ctx) { (void)ctx; }
static void read_joint(void *ctx, float *angle, float *torque, uint8_t *contact)
{
    (void)ctx;
    *angle = joint_angle + (float)(int32_t)(next() % 21) - 10.0f;
    *torque = (float)(int32_t)(next() % 41) / 10.0f - 2.0f;
    *contact = (uint8_t)(next() & 1);
}

static size_t put(uint8_t *out, size_t n, const void *value, size_t size)
{
    memcpy(out + n, value, size); /* little-endian targets: the wire's order */
    return n + size;
}

/* A version-2 program with every field random within its domain (or, one time in eight, a byte changed after). */
static size_t random_program(uint8_t *out)
{
    static const float durations[] = {0.02f, 0.05f, 0.1f, 0.37f, 1.0f, 0.021f, 3600.0f, 0.0199f}; /* the last: refused */
    static const int8_t neighbours[] = {-2, -1, 1};
    uint8_t modes = (uint8_t)(1 + next() % 3), steps = (uint8_t)(next() % 3);
    size_t n = 0;
    out[n++] = 'G', out[n++] = 'T', out[n++] = 2, out[n++] = modes, out[n++] = steps;
    for (uint8_t q = 0; q < steps; q++) {
        uint16_t cycles = (uint16_t)(next() % 4);
        out[n++] = (uint8_t)(next() % modes);
        n = put(out, n, &cycles, 2);
    }
    for (uint8_t m = 0; m < modes; m++) {
        float phase = (float)(next() % 100) / 100.0f;
        uint16_t count = (uint16_t)(1 + next() % 5);
        n = put(out, n, &phase, 4);
        out[n++] = next() % 2 ? 1 : 0xFF, out[n++] = next() % 4 == 0;
        n = put(out, n, &count, 2);
        for (uint16_t k = 0; k < count; k++) {
            float target = (float)(int32_t)(next() % 181) - 90.0f, value = 0.0f;
            float duration = durations[next() % 8];
            uint8_t event = (uint8_t)(next() % 7), timeout = event ? (uint8_t)(next() % 2) : 0;
            int8_t neighbour = event == ASM_EV_NEIGHBOUR ? neighbours[next() % 3] : 0;
            uint16_t watch = event == ASM_EV_NEIGHBOUR ? (uint16_t)(next() % 4) :
                             event == ASM_EV_SIGNAL ? (uint16_t)(1 + next() % 3) : 0;
            if (event && next() % 4 == 0)
                duration = 0.0f; /* no timeout */
            if (event == ASM_EV_AT_GOAL || event == ASM_EV_TORQUE)
                value = (float)(next() % 50) / 10.0f;
            n = put(out, n, &target, 4);
            n = put(out, n, &duration, 4);
            out[n++] = (uint8_t)(next() % 2), out[n++] = event, out[n++] = timeout;
            n = put(out, n, &value, 4);
            out[n++] = (uint8_t)neighbour;
            n = put(out, n, &watch, 2);
            out[n++] = next() % 4 == 0 ? (uint8_t)(1 + next() % 3) : 0;
        }
    }
    if (next() % 8 == 0)
        out[next() % n] = (uint8_t)next();
    return n;
}

/* A request of the module's own, as its application would make it (method on the object of class ``class_id``). */
static void local(uint8_t method, uint8_t class_id, const uint8_t *data, size_t length)
{
    static uint8_t request[ASM_TABLE_BYTES + 8];
    request[0] = (uint8_t)(0x40 | method), request[1] = 0, request[2] = class_id, request[3] = 0;
    if (length)
        memcpy(request + 4, data, length);
    asm_node_local(&module.node, request, 4 + length);
}

/* Now and then a new random program, run; at every call what a running program hears: neighbours' states,
 * signals, switches (random, often out of range). */
static unsigned long drive_program(uint32_t now)
{
    static uint8_t table[ASM_TABLE_BYTES];
    unsigned long loaded = 0;
    if (next() % 512 == 0) {
        size_t n = random_program(table);
        local(5, 0x24, NULL, 0); /* STOP gait.service */
        local(2, 0x20, table, n); /* SET gait.table */
        loaded = asm_table_parse(table, n, module.limits_v, NULL) == ASM_OK;
        local(4, 0x24, NULL, 0); /* START */
    }
    uint8_t r = (uint8_t)(next() % 16);
    if (r == 0) { /* a neighbour's gait.state publication */
        struct asm_can_id id = {ASM_PRIORITY_PUBLICATION, ASM_DEST_BROADCAST, 0, (uint8_t)(5 + next() % 4), 0, 0};
        uint8_t data[6] = {0x7B, 0, 0x23, module.gait.state.id, (uint8_t)(next() % 5), 0};
        asm_node_frame(&module.node, asm_can_pack(&id), data, 6, now);
    } else if (r == 1) {
        uint8_t signal = (uint8_t)(next() % 5);
        local(2, 0x2F, &signal, 1);
    } else if (r == 2) {
        float after = (float)(int32_t)(next() % 200) / 10.0f - 5.0f;
        uint8_t sw[6] = {(uint8_t)(next() % 4), next() % 3 ? 1 : 0xFF};
        memcpy(sw + 2, &after, 4);
        local(2, 0x2B, sw, 6);
    } else if (r == 3) {
        int8_t direction = next() % 2 ? 1 : -1;
        local(2, 0x22, (const uint8_t *)&direction, 1);
    } else if (r == 4 && next() % 8 == 0)
        local(next() % 2 ? 6 : 7, 0x24, NULL, 0); /* SUSPEND or RESUME */
    return loaded;
}

int main(int argc, char **argv)
{
    unsigned long iterations = argc > 1 ? strtoul(argv[1], NULL, 10) : 100000;
    state = argc > 2 ? strtoull(argv[2], NULL, 10) | 1u : 88172645463325252ull;
    static const float limits[2] = {-90.0f, 90.0f};
    static uint8_t message[ASM_MAX_MESSAGE], buffer[ASM_MAX_MESSAGE + 16];
    asm_reassembler_init(&reassembler);
    static const struct asm_port port = {sent, NULL, 0};
    static const struct asm_joint_port joint = {command, relax, read_joint, NULL};
    asm_module_init(&module, "m7", 7, &port, &joint, -90.0f, 90.0f, 0);
    unsigned long completed = 0, parsed = 0, programs = 0, running = 0;
    uint32_t now = 0;
    for (unsigned long k = 0; k < iterations; k++) {
        now += next() % 4096 == 0 ? 3600000u : next() % 50; /* now and then the clock jumps by an hour */
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
        /* the same frame to the module, often addressed to it; or a request to it with random method, IDs, data */
        if (next() % 2) {
            id.dest_kind = ASM_DEST_NODE;
            id.dest = 7;
        }
        if (next() % 3 == 0 && dlc >= 4) {
            id.frame = ASM_SINGLE;
            id.counter = 0;
            dlc = dlc > 8 ? 8 : dlc;
            data[0] = (uint8_t)(0x40 | (next() & 0x1F)); /* version 1, request or request-reply, any method */
            data[2] = (uint8_t)(next() % 2 ? data[2] : 0x10 + next() % 0x25);
            data[3] = (uint8_t)(next() % 26); /* the joint and gait objects, and IDs beyond them */
        }
        asm_node_frame(&module.node, asm_can_pack(&id), data, dlc, now);
        programs += drive_program(now);
        if (next() % 16 == 0) {
            running += module.gait.service.running && !module.node.estop;
            asm_module_tick(&module, now);
        }
        if (module.node.estop && next() % 64 == 0)
            asm_node_set_estop(&module.node, 0); /* released, so programs run again */
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
    /* and the module still answers a lookup of joint.goal, sent as fragments by node 200 */
    static const uint8_t lookup[] = {0x50, 0x01, 0x00, 0x00, 'j', 'o', 'i', 'n', 't', '.', 'g', 'o', 'a', 'l'};
    unsigned long before = replies_to_200;
    asm_fragment_begin(&f, lookup, sizeof lookup, 0);
    while (asm_fragment_next(&f, &frame, &counter, data, &dlc)) {
        struct asm_can_id id = {3, ASM_DEST_NODE, 7, 200, frame, counter};
        asm_node_frame(&module.node, asm_can_pack(&id), data, dlc, now + 1);
    }
    if (replies_to_200 == before) {
        fprintf(stderr, "the module no longer answers a lookup\n");
        return 1;
    }
    printf("fuzzed %lu inputs: %lu messages completed, %lu tables parsed, %lu dropped; the module served %lu "
           "requests and ran %lu random programs (%lu ticks); still answers\n", iterations, completed, parsed,
           (unsigned long)reassembler.dropped, (unsigned long)module.node.served, programs, running);
    return 0;
}
