#include "asm/can.h"

#include <string.h>

#define PREAMBLE 4u
static const uint8_t FD_SIZES[] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64};

#define FIELD(value, name) (((uint32_t)(value) & ASM_CAN_##name##_MASK) << ASM_CAN_##name##_SHIFT)
#define UNFIELD(id, name) ((uint8_t)(((id) >> ASM_CAN_##name##_SHIFT) & ASM_CAN_##name##_MASK))

uint32_t asm_can_pack(const struct asm_can_id *id)
{
    return FIELD(id->priority, PRIORITY) | FIELD(id->dest_kind, DEST_KIND) | FIELD(id->dest, DEST) |
           FIELD(id->source, SOURCE) | FIELD(id->frame, FRAME) | FIELD(id->counter, COUNTER);
}

void asm_can_unpack(uint32_t arbitration_id, struct asm_can_id *id)
{
    id->priority = UNFIELD(arbitration_id, PRIORITY);
    id->dest_kind = UNFIELD(arbitration_id, DEST_KIND);
    id->dest = UNFIELD(arbitration_id, DEST);
    id->source = UNFIELD(arbitration_id, SOURCE);
    id->frame = UNFIELD(arbitration_id, FRAME);
    id->counter = UNFIELD(arbitration_id, COUNTER);
}

static int fd_valid(size_t length)
{
    for (size_t k = 0; k < sizeof FD_SIZES; k++)
        if (FD_SIZES[k] == length)
            return 1;
    return 0;
}

static uint8_t fd_size(size_t length)
{
    for (size_t k = 0; k < sizeof FD_SIZES; k++)
        if (FD_SIZES[k] >= length)
            return FD_SIZES[k];
    return 64;
}

size_t asm_fragment_count(size_t length, int fd)
{
    size_t size = fd ? 64 : 8;
    if (length <= size && (!fd || fd_valid(length)))
        return 1;
    size_t rest = length > size - PREAMBLE ? length - (size - PREAMBLE) : 0;
    return 1 + (rest + size - 1) / size;
}

uint8_t asm_frame_priority(uint8_t priority, size_t frames)
{
    if (frames > 1 && priority == ASM_PRIORITY_PUBLICATION)
        return ASM_PRIORITY_BULK_PUBLICATION;
    if (frames > 1 && priority != ASM_PRIORITY_ESTOP && priority < ASM_PRIORITY_BULK)
        return ASM_PRIORITY_BULK;
    return priority;
}

int asm_fragment_begin(struct asm_fragmenter *f, const uint8_t *message, size_t length, int fd)
{
    if (length > 0xFFFFu)
        return ASM_E_TOO_LARGE;
    f->message = message;
    f->length = length;
    f->offset = 0;
    f->frame_size = fd ? 64 : 8;
    f->counter = 0;
    f->started = 0;
    f->done = 0;
    return ASM_OK;
}

static uint8_t pad(struct asm_fragmenter *f, uint8_t *data, size_t used)
{
    if (f->frame_size == 8 || fd_valid(used))
        return (uint8_t)used;
    uint8_t size = fd_size(used);
    memset(data + used, 0, size - used);
    return size;
}

int asm_fragment_next(struct asm_fragmenter *f, uint8_t *frame, uint8_t *counter, uint8_t *data, uint8_t *dlc)
{
    if (f->done)
        return 0;
    size_t size = f->frame_size;
    if (!f->started) {
        f->started = 1;
        if (f->length <= size && (size == 8 || fd_valid(f->length))) {
            *frame = ASM_SINGLE;
            *counter = 0;
            memcpy(data, f->message, f->length);
            *dlc = (uint8_t)f->length;
            f->done = 1;
            return 1;
        }
        uint16_t crc = asm_crc16(f->message, f->length);
        data[0] = (uint8_t)f->length;
        data[1] = (uint8_t)(f->length >> 8);
        data[2] = (uint8_t)crc;
        data[3] = (uint8_t)(crc >> 8);
        size_t chunk = f->length < size - PREAMBLE ? f->length : size - PREAMBLE;
        memcpy(data + PREAMBLE, f->message, chunk);
        f->offset = size - PREAMBLE;
        *frame = ASM_FIRST;
        *counter = 0;
        *dlc = pad(f, data, PREAMBLE + chunk);
        if (f->offset >= f->length)
            f->done = 1;
        return 1;
    }
    size_t chunk = f->length - f->offset < size ? f->length - f->offset : size;
    memcpy(data, f->message + f->offset, chunk);
    f->offset += size;
    f->counter = (uint8_t)((f->counter + 1) & 0x3F);
    *counter = f->counter;
    *frame = f->offset >= f->length ? ASM_LAST : ASM_MIDDLE;
    *dlc = pad(f, data, chunk);
    if (f->offset >= f->length)
        f->done = 1;
    return 1;
}

void asm_reassembler_init(struct asm_reassembler *r)
{
    memset(r, 0, sizeof *r);
}

static struct asm_partial *find(struct asm_reassembler *r, const struct asm_can_id *id)
{
    for (size_t k = 0; k < ASM_CAN_PARTIALS; k++) {
        struct asm_partial *p = &r->slots[k];
        if (p->used && p->source == id->source && p->dest_kind == id->dest_kind && p->dest == id->dest)
            return p;
    }
    return NULL;
}

static int drop(struct asm_reassembler *r)
{
    r->dropped++;
    return 0;
}

static int same_as_last(const struct asm_partial *p, const uint8_t *data, uint8_t dlc)
{
    return p->last_length == dlc && memcmp(p->last, data, dlc) == 0;
}

static void remember(struct asm_partial *p, const uint8_t *data, uint8_t dlc, uint32_t now_ms)
{
    memcpy(p->last, data, dlc);
    p->last_length = dlc;
    p->touched_ms = now_ms;
}

/* A partial message that has all its bytes: complete (1) or dropped (0). */
static int check(struct asm_reassembler *r, struct asm_partial *p, int last, const uint8_t **message, size_t *length)
{
    if (p->have < p->length) {
        if (last) {
            p->used = 0;
            return drop(r);
        }
        return 0;
    }
    p->used = 0;
    if (p->have - p->length >= 64 || asm_crc16(p->data, p->length) != p->crc)
        return drop(r);
    *message = p->data;
    *length = p->length;
    return 1;
}

int asm_reassemble(struct asm_reassembler *r, const struct asm_can_id *id, const uint8_t *data, uint8_t dlc,
                   uint32_t now_ms, const uint8_t **message, size_t *length)
{
    if (dlc > 64)
        return drop(r);
    if (id->frame == ASM_SINGLE) {
        *message = data;
        *length = dlc;
        return 1;
    }
    struct asm_partial *p = find(r, id);
    if (id->frame == ASM_FIRST) {
        if (p != NULL && p->counter == 0 && same_as_last(p, data, dlc))
            return drop(r); /* CAN's double reception */
        if (p != NULL) {
            p->used = 0; /* a first frame restarts the message of its key */
            r->dropped++;
        }
        if (dlc < PREAMBLE || id->counter != 0)
            return drop(r);
        uint16_t announced = (uint16_t)(data[0] | (data[1] << 8));
        if (announced > ASM_CAN_MAX_MESSAGE)
            return drop(r);
        p = NULL;
        for (size_t k = 0; k < ASM_CAN_PARTIALS && p == NULL; k++)
            if (!r->slots[k].used)
                p = &r->slots[k];
        if (p == NULL) { /* evict the least recently touched */
            p = &r->slots[0];
            for (size_t k = 1; k < ASM_CAN_PARTIALS; k++)
                if ((int32_t)(r->slots[k].touched_ms - p->touched_ms) < 0)
                    p = &r->slots[k];
            r->dropped++;
        }
        p->used = 1;
        p->source = id->source;
        p->dest_kind = id->dest_kind;
        p->dest = id->dest;
        p->counter = 0;
        p->length = announced;
        p->crc = (uint16_t)(data[2] | (data[3] << 8));
        p->have = (size_t)(dlc - PREAMBLE);
        memcpy(p->data, data + PREAMBLE, p->have);
        remember(p, data, dlc, now_ms);
        return check(r, p, 0, message, length);
    }
    if (p == NULL)
        return drop(r); /* an orphan fragment */
    if (id->counter == p->counter && same_as_last(p, data, dlc))
        return drop(r);
    if (id->counter != ((p->counter + 1) & 0x3F)) {
        p->used = 0;
        return drop(r);
    }
    p->counter = id->counter;
    memcpy(p->data + p->have, data, dlc); /* have < length <= ASM_CAN_MAX_MESSAGE here: room for one frame more */
    p->have += dlc;
    remember(p, data, dlc, now_ms);
    return check(r, p, id->frame == ASM_LAST, message, length);
}

void asm_reassembler_expire(struct asm_reassembler *r, uint32_t now_ms)
{
    for (size_t k = 0; k < ASM_CAN_PARTIALS; k++) {
        struct asm_partial *p = &r->slots[k];
        if (p->used && now_ms - p->touched_ms > ASM_CAN_TIMEOUT_MS) {
            p->used = 0;
            r->dropped++;
        }
    }
}
