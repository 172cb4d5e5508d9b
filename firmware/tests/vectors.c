/* Golden-vector runner: reads one case per line on stdin (tests/test_firmware.py writes them from tests/vectors/
 * and from the Python implementation), checks the C implementation gives the same bytes, prints "ok N" or the
 * failing lines, and exits 1 on any failure.
 *
 *   MSG <hex> <kind> <method> <txn> <class> <status> <object> <timeout|-1>     decode, then encode back
 *   CAN <fd> <priority> <dest_kind> <dest> <source> <message hex> <id>:<data> ...  fragment, then reassemble
 *   TABLE <ok|refused> <hex> <crc32>                                              parse; CRC-32 of the bytes
 *   TIMEOUT <ms> <code>                                                           the timeout byte both ways */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asm/can.h"
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
        else
            fail("unknown case", original);
    }
    printf("ok %d failed %d\n", cases - failures, failures);
    return failures ? 1 : 0;
}
