#include "asm/codec.h"

#include "asm/wire.h"

int asm_utf8_valid(const uint8_t *s, size_t length)
{
    for (size_t k = 0; k < length;) {
        uint8_t c = s[k], lo = 0x80, hi = 0xBF;
        size_t more = c < 0x80 ? 0 : c < 0xC2 ? 9 : c < 0xE0 ? 1 : c < 0xF0 ? 2 : c < 0xF5 ? 3 : 9;
        if (more == 9 || k + more >= length + (more == 0))
            return 0;
        if (c == 0xE0) lo = 0xA0;
        if (c == 0xED) hi = 0x9F;
        if (c == 0xF0) lo = 0x90;
        if (c == 0xF4) hi = 0x8F;
        for (size_t j = 1; j <= more; j++, lo = 0x80, hi = 0xBF)
            if (s[k + j] < lo || s[k + j] > hi)
                return 0;
        k += more + 1;
    }
    return 1;
}

/* LEB128 at *at (at most 4 bytes: lengths within a message); -1 when malformed or past ``end``. */
static long leb128(const uint8_t *p, size_t *at, size_t end)
{
    unsigned long value = 0;
    for (unsigned shift = 0; shift < 28; shift += 7) {
        if (*at >= end)
            return -1;
        uint8_t b = p[(*at)++];
        value |= (unsigned long)(b & 0x7Fu) << shift;
        if (!(b & 0x80u))
            return (long)value;
    }
    return -1;
}

static const uint8_t SIZES[] = {0, 1, 1, 2, 4, 8, 1, 2, 4, 8, 4, 8}; /* by tag 0x01..0x0B */

/* One value of the codec at descriptor[*d] from data[*at]; ``last``: it runs to the end of the data. */
static int check(const uint8_t *desc, size_t *d, size_t dend, const uint8_t *data, size_t *at, size_t end, int last)
{
    if (*d >= dend)
        return ASM_E_FORMAT;
    uint8_t tag = desc[(*d)++];
    if (tag >= 0x01 && tag <= 0x0B) {
        if (end - *at < SIZES[tag])
            return ASM_E_FORMAT;
        if (tag == 0x01 && data[*at] > 1)
            return ASM_E_FORMAT;
        *at += SIZES[tag];
        return ASM_OK;
    }
    if (tag == 0x0C || tag == 0x0D || tag == 0x10) { /* str, bytes (max length), json */
        long max = tag == 0x10 ? 0 : leb128(desc, d, dend);
        long n = last ? (long)(end - *at) : leb128(data, at, end); /* inside a record: prefixed by its length */
        if (max < 0 || n < 0 || (size_t)n > end - *at || (max > 0 && n > max))
            return ASM_E_FORMAT;
        if (tag != 0x0D && !asm_utf8_valid(data + *at, (size_t)n))
            return ASM_E_FORMAT;
        *at += (size_t)n;
        return ASM_OK;
    }
    if (tag == 0x0E) { /* float array: element tag, count */
        uint8_t element = *d < dend ? desc[(*d)++] : 0;
        long count = leb128(desc, d, dend);
        size_t size = element == 0x0A ? 4 : element == 0x0B ? 8 : 0;
        if (size == 0 || count < 0 || (size_t)count > (end - *at) / size)
            return ASM_E_FORMAT;
        *at += size * (size_t)count;
        return ASM_OK;
    }
    if (tag == 0x0F) { /* record: fields in order, a str/bytes/json field prefixed by its length */
        long fields = leb128(desc, d, dend);
        if (fields < 0)
            return ASM_E_FORMAT;
        for (long f = 0; f < fields; f++) {
            long name = leb128(desc, d, dend);
            if (name < 0 || (size_t)name > dend - *d)
                return ASM_E_FORMAT;
            *d += (size_t)name;
            if (check(desc, d, dend, data, at, end, 0) != ASM_OK)
                return ASM_E_FORMAT;
        }
        return ASM_OK;
    }
    return ASM_E_FORMAT;
}

int asm_codec_check(const uint8_t *descriptor, size_t descriptor_length, const uint8_t *data, size_t length)
{
    size_t d = 0, at = 0;
    if (check(descriptor, &d, descriptor_length, data, &at, length, 1) != ASM_OK)
        return ASM_E_FORMAT;
    return d == descriptor_length && at == length ? ASM_OK : ASM_E_FORMAT;
}
