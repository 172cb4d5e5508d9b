#include "asm/wire.h"

long asm_encode(const struct asm_message *m, uint8_t *out, size_t size)
{
    if (m->method > ASM_METHOD_MASK || m->txn > ASM_MAX_TXN || m->kind > ASM_PUBLICATION)
        return ASM_E_RANGE;
    int has_timeout = m->timeout >= 0;
    if (has_timeout && (m->kind == ASM_REPLY || m->timeout > 0xFF))
        return ASM_E_RANGE;
    size_t total = ASM_HEADER_SIZE + (has_timeout ? 1u : 0u) + m->length;
    if (total > ASM_MAX_MESSAGE || total > size)
        return ASM_E_TOO_LARGE;
    out[0] = asm_first_byte(m->kind, m->method);
    out[1] = asm_second_byte(has_timeout, m->txn);
    out[2] = m->kind == ASM_REPLY ? m->status : m->class_id;
    out[3] = m->object_id;
    size_t offset = ASM_HEADER_SIZE;
    if (has_timeout)
        out[offset++] = (uint8_t)m->timeout;
    for (size_t k = 0; k < m->length; k++)
        out[offset + k] = m->data[k];
    return (long)total;
}

int asm_decode(const uint8_t *raw, size_t length, struct asm_message *m)
{
    if (length < ASM_HEADER_SIZE)
        return ASM_E_SHORT;
    if (length > ASM_MAX_MESSAGE)
        return ASM_E_TOO_LARGE;
    if (asm_version_of(raw[0]) != ASM_VERSION)
        return ASM_E_VERSION;
    m->kind = (uint8_t)asm_kind_of(raw[0]);
    m->method = (uint8_t)asm_method_of(raw[0]);
    m->txn = raw[1] & ASM_MAX_TXN;
    m->object_id = raw[3];
    m->timeout = -1;
    size_t offset = ASM_HEADER_SIZE;
    if (asm_has_timeout(raw[1])) {
        if (m->kind == ASM_REPLY || length < ASM_HEADER_SIZE + 1)
            return ASM_E_FORMAT;
        m->timeout = raw[ASM_HEADER_SIZE];
        offset++;
    }
    if (m->kind == ASM_REPLY) {
        m->status = raw[2];
        m->class_id = 0;
    } else {
        m->status = 0;
        m->class_id = raw[2];
    }
    m->data = raw + offset;
    m->length = length - offset;
    return ASM_OK;
}

uint8_t asm_timeout_code(uint32_t ms)
{
    if (ms == UINT32_MAX)
        return ASM_FOREVER;
    if (ms < 16)
        return (uint8_t)ms;
    unsigned bits = 0;
    for (uint32_t v = ms; v; v >>= 1)
        bits++;
    unsigned exponent = bits - 4; /* so that ms >> (exponent - 1) is in 16..31 */
    if (exponent > 15)
        return 0xFE;
    unsigned code = (exponent << 4) | ((ms >> (exponent - 1)) - 16);
    return (uint8_t)(code > 0xFE ? 0xFE : code);
}

uint32_t asm_timeout_ms(uint8_t code)
{
    if (code == ASM_FOREVER)
        return UINT32_MAX;
    unsigned exponent = code >> 4, mantissa = code & 0x0F;
    return exponent == 0 ? mantissa : (16u + mantissa) << (exponent - 1);
}

uint16_t asm_crc16(const uint8_t *data, size_t length)
{
    uint16_t crc = 0xFFFF;
    for (size_t k = 0; k < length; k++) {
        crc ^= (uint16_t)(data[k] << 8);
        for (int bit = 0; bit < 8; bit++)
            crc = (uint16_t)((crc & 0x8000) ? (crc << 1) ^ 0x1021 : crc << 1);
    }
    return crc;
}

/* The bit loop unrolled: a board checks whole firmware images with it (64 KiB at most), a branch a bit otherwise. */
uint32_t asm_crc32(const uint8_t *data, size_t length)
{
    uint32_t crc = 0xFFFFFFFFu;
#define ASM_CRC32_BIT crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)))
    for (size_t k = 0; k < length; k++) {
        crc ^= data[k];
        ASM_CRC32_BIT;
        ASM_CRC32_BIT;
        ASM_CRC32_BIT;
        ASM_CRC32_BIT;
        ASM_CRC32_BIT;
        ASM_CRC32_BIT;
        ASM_CRC32_BIT;
        ASM_CRC32_BIT;
    }
#undef ASM_CRC32_BIT
    return ~crc;
}

/* floor(n / 1000) of a 64-bit n with 32-bit divisions (16 bits at a time), the remainder in *rest. */
static uint64_t div1000(uint64_t n, uint32_t *rest)
{
    uint64_t quotient = 0;
    uint32_t remainder = 0;
    for (int shift = 48; shift >= 0; shift -= 16) {
        uint32_t part = remainder << 16 | (uint32_t)(n >> shift & 0xFFFFu);
        quotient = quotient << 16 | part / 1000u;
        remainder = part % 1000u;
    }
    *rest = remainder;
    return quotient;
}

uint64_t asm_seconds_f64(uint32_t ms)
{
    if (ms == 0)
        return 0;
    /* scale so the quotient has 54 bits: 53 of mantissa and a guard bit; the remainder is the sticky bit */
    int scale = 54;
    for (uint32_t v = ms; v >= 1000u; v >>= 1)
        scale--;
    uint32_t rest;
    uint64_t q = div1000((uint64_t)ms << scale, &rest);
    while (q >> 54) {
        scale--;
        q = div1000((uint64_t)ms << scale, &rest);
    }
    while (!(q >> 53)) {
        scale++;
        q = div1000((uint64_t)ms << scale, &rest);
    }
    uint32_t guard = (uint32_t)(q & 1u);
    uint32_t sticky = rest != 0;
    uint64_t mantissa = q >> 1;
    if (guard && (sticky || (mantissa & 1u)))
        mantissa++;
    int exponent = 53 - scale; /* value = mantissa / 2^52 * 2^exponent */
    if (mantissa >> 53) {
        mantissa >>= 1;
        exponent++;
    }
    return (uint64_t)(exponent + 1023) << 52 | (mantissa & ((1ull << 52) - 1u));
}
