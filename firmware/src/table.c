#include "asm/table.h"

#include <math.h>
#include <string.h>

#include "asm/wire.h"

static int within(float target, const float limits[2])
{
    return isfinite(target) && target >= limits[0] && target <= limits[1];
}

static int parse_v1(const uint8_t *data, size_t length, const float limits[2], struct asm_program *p)
{
    uint16_t n = asm_get_u16(data + 3);
    if (n < 1 || n > ASM_PROTOCOL_MAX_STATES || length != 5u + 9u * n)
        return ASM_E_FORMAT;
    for (uint16_t k = 0; k < n; k++) {
        const uint8_t *s = data + 5 + 9u * k;
        float angle = asm_get_f32(s), duration = asm_get_f32(s + 4);
        if (s[8] > 1 || !isfinite(duration) || !(duration >= ASM_MIN_DURATION) || !isfinite(angle))
            return ASM_E_FORMAT;
        if (!within(angle, limits))
            return ASM_E_RANGE;
        if (k >= ASM_MAX_STATES)
            return ASM_E_TOO_LARGE;
        if (p != NULL)
            p->states[k] = (struct asm_state){.target = angle, .duration = duration, .linear = s[8]};
    }
    if (p == NULL)
        return ASM_OK;
    p->version = 1;
    p->modes_n = 1;
    p->states_n = n;
    p->modes[0] = (struct asm_mode){.phase = 0, .direction = 1, .one_shot = 0, .first = 0, .count = n};
    return ASM_OK;
}

/* The checks of asm_module/wire.py decode_program, in the same order of importance. */
static int parse_state(const uint8_t *s, struct asm_state *out)
{
    float angle = asm_get_f32(s), duration = asm_get_f32(s + 4), value = asm_get_f32(s + 11);
    uint8_t interp = s[8], event = s[9], timeout = s[10], emit = s[18];
    int8_t neighbour = (int8_t)s[15];
    uint16_t watch = asm_get_u16(s + 16);
    if (interp > 1 || event > ASM_EV_SIGNAL || timeout > 1)
        return ASM_E_FORMAT;
    /* one form per program: what an event does not use is 0 */
    if ((event == ASM_EV_NONE && timeout) || (event != ASM_EV_AT_GOAL && event != ASM_EV_TORQUE && value != 0.0f) ||
        (event != ASM_EV_NEIGHBOUR && neighbour) || (event != ASM_EV_NEIGHBOUR && event != ASM_EV_SIGNAL && watch))
        return ASM_E_FORMAT;
    if (!isfinite(angle) || !isfinite(duration) || !isfinite(value) || value < 0 || duration < 0)
        return ASM_E_FORMAT;
    if (duration == 0 && event == ASM_EV_NONE)
        return ASM_E_FORMAT; /* a state needs a duration, an event, or both */
    if (duration != 0 && !(duration >= ASM_MIN_DURATION))
        return ASM_E_FORMAT; /* no state shorter than one control tick */
    if (event == ASM_EV_NEIGHBOUR && neighbour == 0)
        return ASM_E_FORMAT;
    if (event == ASM_EV_SIGNAL && (watch < 1 || watch > 255))
        return ASM_E_FORMAT;
    *out = (struct asm_state){.target = angle, .duration = duration, .value = value, .watch = watch, .linear = interp,
                              .event = event, .stop_on_timeout = timeout, .neighbour = neighbour, .emit = emit};
    return ASM_OK;
}

static int parse_v2(const uint8_t *data, size_t length, const float limits[2], struct asm_program *p)
{
    if (length < 5)
        return ASM_E_FORMAT;
    uint8_t modes = data[3], steps = data[4];
    if (modes < 1 || modes > ASM_MAX_MODES || steps > ASM_MAX_SEQUENCE)
        return ASM_E_FORMAT;
    size_t offset = 5;
    if (offset + 3u * steps > length)
        return ASM_E_FORMAT;
    for (uint8_t q = 0; q < steps && p != NULL; q++) {
        p->sequence[q].mode = data[offset + 3u * q];
        p->sequence[q].cycles = asm_get_u16(data + offset + 3u * q + 1);
    }
    offset += 3u * steps;
    uint32_t total = 0;
    int too_many = 0, outside = 0, simple = modes == 1 && steps == 0;
    for (uint8_t m = 0; m < modes; m++) {
        if (offset + 8 > length)
            return ASM_E_FORMAT;
        float phase = asm_get_f32(data + offset);
        int8_t direction = (int8_t)data[offset + 4];
        uint8_t flags = data[offset + 5];
        uint16_t n = asm_get_u16(data + offset + 6);
        offset += 8;
        total += n;
        if (n < 1 || total > ASM_PROTOCOL_MAX_STATES || (flags & ~1u))
            return ASM_E_FORMAT;
        if (offset + 19u * n > length)
            return ASM_E_FORMAT;
        if (!(phase >= 0.0f && phase < 1.0f) || (direction != 1 && direction != -1))
            return ASM_E_FORMAT;
        simple &= !(flags & 1u);
        if (p != NULL)
            p->modes[m] = (struct asm_mode){phase, direction, (uint8_t)(flags & 1u), (uint16_t)(total - n), n};
        for (uint16_t k = 0; k < n; k++, offset += 19) {
            struct asm_state state;
            int status = parse_state(data + offset, &state);
            if (status != ASM_OK)
                return status;
            outside |= !within(state.target, limits);
            simple &= state.event == ASM_EV_NONE && state.emit == 0;
            if (total - n + k >= ASM_MAX_STATES)
                too_many = 1;
            else if (p != NULL)
                p->states[total - n + k] = state;
        }
    }
    if (offset != length)
        return ASM_E_FORMAT;
    for (uint8_t q = 0; q < steps; q++)
        if (data[5 + 3u * q] >= modes)
            return ASM_E_FORMAT;
    if (simple) /* what version 1 says is never version 2 (one program, one form, one checksum) */
        return ASM_E_FORMAT;
    if (outside)
        return ASM_E_RANGE;
    if (too_many)
        return ASM_E_TOO_LARGE;
    if (p != NULL) {
        p->version = 2;
        p->modes_n = modes;
        p->sequence_n = steps;
        p->states_n = (uint16_t)total;
    }
    return ASM_OK;
}

int asm_table_parse(const uint8_t *data, size_t length, const float limits[2], struct asm_program *program)
{
    if (length < 5 || data[0] != 'G' || data[1] != 'T')
        return ASM_E_FORMAT;
    if (data[2] == 1)
        return parse_v1(data, length, limits, program);
    if (data[2] == 2)
        return parse_v2(data, length, limits, program);
    return ASM_E_FORMAT;
}
