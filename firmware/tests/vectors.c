/* Golden-vector runner: reads one case per line on stdin (tests/firmware/test_firmware.py writes them from
 * tests/vectors/ and from the Python implementation), checks the C implementation gives the same bytes, prints "ok N"
 * or the failing lines, and exits 1 on any failure.
 *
 *   MSG <hex> <kind> <method> <txn> <class> <status> <object> <timeout|-1>     decode, then encode back
 *   CAN <fd> <priority> <dest_kind> <dest> <source> <message hex> <id>:<data> ...  fragment, then reassemble
 *   TABLE <ok|refused> <hex> <crc32>                                              parse; CRC-32 of the bytes
 *   TIMEOUT <ms> <code>                                                           the timeout byte both ways
 *   SECONDS <ms> <hex>                                  ms / 1000 as float64 bits, little-endian (gait.tick)
 *   CODEC <ok|refused> <descriptor hex> <value hex> [token ...]   check the value's bytes against the descriptor;
 *         with tokens (one per scalar, str/bytes/json as hex), encode them and compare with the value's bytes */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asm/can.h"
#include "asm/codec.h"
#include "asm/table.h"
#include "asm/wire.h"

#define LINE 200000

static char line[LINE];
static uint8_t bytes[70000], other[70000];
static int failures;
static struct asm_reassembler reassembler;
static struct asm_program program;

static size_t unhex(const char *text, uint8_t *out)
{
    size_t n = 0;
    if (strcmp(text, "-") == 0)
        return 0;
    for (; text[0] && text[1]; text += 2) {
        unsigned value;
        sscanf(text, "%2x", &value);
        out[n++] = (uint8_t)value;
    }
    return n;
}

static void fail(const char *what, const char *case_line)
{
    failures++;
    if (failures <= 20)
        fprintf(stderr, "FAIL %s: %.300s\n", what, case_line);
}

static void message_case(char *rest, const char *original)
{
    char hex[LINE];
    int kind, method, txn, class_id, status, object, timeout;
    if (sscanf(rest, "%s %d %d %d %d %d %d %d", hex, &kind, &method, &txn, &class_id, &status, &object, &timeout) != 8)
        {
        fail("MSG syntax", original);
        return;
    }
    size_t n = unhex(hex, bytes);
    struct asm_message m;
    if (asm_decode(bytes, n, &m) != ASM_OK)
        {
        fail("MSG decode", original);
        return;
    }
    if (m.kind != kind || m.method != method || m.txn != txn || m.class_id != class_id || m.status != status ||
        m.object_id != object || m.timeout != timeout)
        {
        fail("MSG fields", original);
        return;
    }
    long written = asm_encode(&m, other, sizeof other);
    if (written != (long)n || memcmp(bytes, other, n) != 0)
        {
        fail("MSG encode", original);
        return;
    }
}

static void can_case(char *rest, const char *original)
{
    int fd, priority, dest_kind, dest, source, used;
    char hex[LINE];
    if (sscanf(rest, "%d %d %d %d %d %s%n", &fd, &priority, &dest_kind, &dest, &source, hex, &used) != 6)
        {
        fail("CAN syntax", original);
        return;
    }
    size_t n = unhex(hex, bytes);
    struct asm_fragmenter f;
    if (asm_fragment_begin(&f, bytes, n, fd) != ASM_OK)
        {
        fail("CAN begin", original);
        return;
    }
    char *expected = rest + used;
    uint8_t frame, counter, data[64], dlc, want[64]; /* a SINGLE frame's message is ``want`` itself */
    const uint8_t *message = NULL;
    size_t length = 0;
    int complete = 0;
    while (asm_fragment_next(&f, &frame, &counter, data, &dlc)) {
        uint8_t at = asm_frame_priority((uint8_t)priority, asm_fragment_count(n, fd));
        struct asm_can_id id = {at, (uint8_t)dest_kind, (uint8_t)dest, (uint8_t)source, frame, counter};
        unsigned long want_id;
        char want_data[200];
        int consumed;
        if (sscanf(expected, " %lx:%199s%n", &want_id, want_data, &consumed) != 2)
            {
        fail("CAN more frames than expected", original);
        return;
    }
        expected += consumed;
        size_t want_n = unhex(want_data, want);
        if (asm_can_pack(&id) != want_id || want_n != dlc || memcmp(want, data, dlc) != 0)
            {
        fail("CAN frame", original);
        return;
    }
        struct asm_can_id back;
        asm_can_unpack((uint32_t)want_id, &back);
        if (memcmp(&back, &id, sizeof id) != 0)
            {
        fail("CAN unpack", original);
        return;
    }
        complete = asm_reassemble(&reassembler, &back, want, (uint8_t)want_n, 0, &message, &length);
    }
    if (sscanf(expected, " %*s") != EOF && strspn(expected, " \n") != strlen(expected))
        {
        fail("CAN fewer frames than expected", original);
        return;
    }
    if (!complete || length != n || memcmp(message, bytes, n) != 0)
        {
        fail("CAN reassembly", original);
        return;
    }
}

static void table_case(char *rest, const char *original)
{
    char verdict[16], hex[LINE];
    unsigned long crc;
    if (sscanf(rest, "%15s %s %lx", verdict, hex, &crc) != 3)
        {
        fail("TABLE syntax", original);
        return;
    }
    size_t n = unhex(hex, bytes);
    static const float limits[2] = {-90.0f, 90.0f};
    int status = asm_table_parse(bytes, n, limits, &program);
    int ok = status == ASM_OK || status == ASM_E_TOO_LARGE; /* too many for this module, yet a valid table */
    if (ok != (strcmp(verdict, "ok") == 0))
        {
        fail(ok ? "TABLE accepted what Python refuses" : "TABLE refused what Python accepts", original);
        return;
    }
    if (asm_crc32(bytes, n) != (uint32_t)crc)
        {
        fail("TABLE crc32", original);
        return;
    }
}

static void timeout_case(char *rest, const char *original)
{
    unsigned long ms;
    unsigned code;
    if (sscanf(rest, "%lu %u", &ms, &code) != 2)
        {
        fail("TIMEOUT syntax", original);
        return;
    }
    if (asm_timeout_code((uint32_t)ms) != code)
        {
        fail("TIMEOUT code", original);
        return;
    }
}

static void seconds_case(char *rest, const char *original)
{
    unsigned long ms;
    char hex[40];
    if (sscanf(rest, "%lu %39s", &ms, hex) != 2 || unhex(hex, bytes) != 8) {
        fail("SECONDS syntax", original);
        return;
    }
    uint64_t bits = asm_seconds_f64((uint32_t)ms), expected = 0;
    for (int i = 7; i >= 0; i--)
        expected = expected << 8 | bytes[i];
    if (bits != expected)
        fail("SECONDS bits", original);
}

static size_t put_leb128(uint8_t *out, size_t length)
{
    size_t n = 0;
    do {
        out[n] = (uint8_t)(length & 0x7Fu);
        length >>= 7;
        out[n] |= length ? 0x80u : 0;
        n++;
    } while (length);
    return n;
}

static long get_leb128(const uint8_t *p, size_t *at)
{
    unsigned long value = 0;
    for (unsigned shift = 0;; shift += 7) {
        uint8_t b = p[(*at)++];
        value |= (unsigned long)(b & 0x7Fu) << shift;
        if (!(b & 0x80u))
            return (long)value;
    }
}

/* Encode the tokens as the codec at desc[*d] says, as a firmware writes a value: little-endian scalars, a
 * length-prefixed str/bytes/json inside a record, float arrays element by element. Returns bytes written. */
static size_t encode(const uint8_t *desc, size_t *d, char **tokens, int *t, uint8_t *out, int last)
{
    static const uint8_t SIZES[] = {0, 1, 1, 2, 4, 8, 1, 2, 4, 8, 4, 8};
    uint8_t tag = desc[(*d)++];
    size_t n = 0;
    if (tag <= 0x09) {
        const char *token = tokens[(*t)++];
        unsigned long long v = token[0] == '-' ? (unsigned long long)strtoll(token, NULL, 10) : strtoull(token, NULL, 10);
        for (uint8_t k = 0; k < SIZES[tag]; k++)
            out[n++] = (uint8_t)(v >> (8 * k));
    } else if (tag == 0x0A || tag == 0x0B) {
        double v = strtod(tokens[(*t)++], NULL);
        if (tag == 0x0A) {
            float f = (float)v;
            memcpy(out, &f, 4);
            n = 4;
        } else {
            memcpy(out, &v, 8);
            n = 8;
        }
    } else if (tag == 0x0C || tag == 0x0D || tag == 0x10) {
        if (tag != 0x10)
            get_leb128(desc, d);
        size_t raw = unhex(tokens[(*t)++], other);
        if (!last)
            n = put_leb128(out, raw);
        memcpy(out + n, other, raw);
        n += raw;
    } else if (tag == 0x0E) {
        uint8_t element[1] = {desc[(*d)++]};
        long count = get_leb128(desc, d);
        for (long k = 0; k < count; k++) {
            size_t e = 0;
            n += encode(element, &e, tokens, t, out + n, 0);
        }
    } else if (tag == 0x0F) {
        long fields = get_leb128(desc, d);
        for (long f = 0; f < fields; f++) {
            long name = get_leb128(desc, d);
            *d += (size_t)name;
            n += encode(desc, d, tokens, t, out + n, 0);
        }
    }
    return n;
}

static void codec_case(char *rest, const char *original)
{
    static uint8_t descriptor[256], encoded[4096];
    char *tokens[512], *verdict = strtok(rest, " \n"), *desc_hex = strtok(NULL, " \n"), *value_hex = strtok(NULL, " \n");
    int count = 0;
    if (verdict == NULL || desc_hex == NULL || value_hex == NULL) {
        fail("CODEC syntax", original);
        return;
    }
    for (char *token = strtok(NULL, " \n"); token != NULL && count < 512; token = strtok(NULL, " \n"))
        tokens[count++] = token;
    size_t dn = unhex(desc_hex, descriptor), n = unhex(value_hex, bytes);
    int ok = asm_codec_check(descriptor, dn, bytes, n) == ASM_OK;
    if (ok != (strcmp(verdict, "ok") == 0)) {
        fail(ok ? "CODEC accepted what Python refuses" : "CODEC refused what Python accepts", original);
        return;
    }
    if (count) {
        size_t d = 0;
        int t = 0;
        size_t written = encode(descriptor, &d, tokens, &t, encoded, 1);
        if (written != n || memcmp(encoded, bytes, n) != 0)
            fail("CODEC encode", original);
    }
}

int main(void)
{
    int cases = 0;
    asm_reassembler_init(&reassembler);
    while (fgets(line, sizeof line, stdin)) {
        char original[400];
        memcpy(original, line, sizeof original - 1); /* the start of the line, for messages */
        original[sizeof original - 1] = '\0';
        char *rest = strchr(line, ' ');
        if (rest == NULL)
            continue;
        *rest++ = '\0';
        cases++;
        if (strcmp(line, "MSG") == 0)
            message_case(rest, original);
        else if (strcmp(line, "CAN") == 0)
            can_case(rest, original);
        else if (strcmp(line, "TABLE") == 0)
            table_case(rest, original);
        else if (strcmp(line, "TIMEOUT") == 0)
            timeout_case(rest, original);
        else if (strcmp(line, "SECONDS") == 0)
            seconds_case(rest, original);
        else if (strcmp(line, "CODEC") == 0)
            codec_case(rest, original);
        else
            fail("unknown case", original);
    }
    printf("ok %d failed %d\n", cases - failures, failures);
    return failures ? 1 : 0;
}
