/* The ASM message (docs/protocol.md sections 1-2) and the checksums every part of the protocol uses.
 *
 * No allocation, no OS: every function works on caller-owned buffers and returns a status. */
#ifndef ASM_WIRE_H
#define ASM_WIRE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "asm/contract.h" /* the protocol's numbers: generated from contract/asm.toml */

enum asm_result {
    ASM_OK = 0,
    ASM_E_SHORT = -1,     /* fewer bytes than the header (and its timeout byte) need */
    ASM_E_VERSION = -2,   /* a protocol version this implementation does not speak */
    ASM_E_RANGE = -3,     /* a field out of its range */
    ASM_E_TOO_LARGE = -4, /* longer than ASM_MAX_MESSAGE or the caller's buffer */
    ASM_E_FORMAT = -5     /* malformed content */
};

/* One decoded message. ``data`` points into the buffer it was decoded from (no copy). */
struct asm_message {
    uint8_t kind;      /* enum asm_kind */
    uint8_t method;    /* 0..15 */
    uint8_t txn;       /* 0..127 (publications: sequence number) */
    uint8_t class_id;  /* requests and publications */
    uint8_t status;    /* replies */
    uint8_t object_id;
    int16_t timeout;   /* the raw timeout byte of a request, or -1 when absent */
    const uint8_t *data;
    size_t length;     /* bytes of data */
};

/* Byte 0 of a message (version, kind, method) and byte 1's flag and transaction, laid out in this one place. */
static inline uint8_t asm_first_byte(unsigned kind, unsigned method)
{
    return (uint8_t)((ASM_VERSION << ASM_VERSION_SHIFT) | (kind << ASM_KIND_SHIFT) | (method & ASM_METHOD_MASK));
}
static inline unsigned asm_version_of(uint8_t b0) { return (b0 >> ASM_VERSION_SHIFT) & ASM_VERSION_MASK; }
static inline unsigned asm_kind_of(uint8_t b0) { return (b0 >> ASM_KIND_SHIFT) & ASM_KIND_MASK; }
static inline unsigned asm_method_of(uint8_t b0) { return b0 & ASM_METHOD_MASK; }
static inline unsigned asm_has_timeout(uint8_t b1) { return (b1 >> ASM_TIMEOUT_FLAG_SHIFT) & ASM_TIMEOUT_FLAG_MASK; }
static inline uint8_t asm_second_byte(unsigned has_timeout, unsigned txn)
{
    return (uint8_t)((has_timeout ? ASM_TIMEOUT_FLAG_MASK << ASM_TIMEOUT_FLAG_SHIFT : 0u) | (txn & ASM_TXN_MASK));
}

/* Encode ``m`` into ``out`` (capacity ``size``); the number of bytes written, or a negative asm_result. */
long asm_encode(const struct asm_message *m, uint8_t *out, size_t size);
/* Decode ``raw``; ASM_OK or a negative asm_result (``m`` is then undefined). */
int asm_decode(const uint8_t *raw, size_t length, struct asm_message *m);

/* The timeout byte for ``ms`` milliseconds, rounded down (ASM_FOREVER for UINT32_MAX), and back (UINT32_MAX for
 * ASM_FOREVER). */
uint8_t asm_timeout_code(uint32_t ms);
uint32_t asm_timeout_ms(uint8_t code);

/* Little-endian fields of messages and tables. */
static inline uint16_t asm_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }
static inline uint32_t asm_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static inline float asm_get_f32(const uint8_t *p)
{
    uint32_t bits = asm_get_u32(p);
    float value;
    memcpy(&value, &bits, sizeof value);
    return value;
}

/* The IEEE 754 binary64 bits of ``ms`` / 1000 seconds, rounded to nearest-even as a double division would round,
 * in integer arithmetic: a Cortex-M4's FPU has no double precision, and its soft-float division costs 2 KiB. */
uint64_t asm_seconds_f64(uint32_t ms);

uint16_t asm_crc16(const uint8_t *data, size_t length); /* CRC-16/CCITT-FALSE: CAN fragment preambles */
uint32_t asm_crc32(const uint8_t *data, size_t length); /* CRC-32 (IEEE, zlib's): gait.checksum */

#endif
