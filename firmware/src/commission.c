/* Commissioning, a module's side (asm/commission.h; docs/protocol.md section 7). */
#include "asm/commission.h"


#define POSITION_BITS 4u

void asm_commission_init(struct asm_commission *c, const uint8_t *serial, uint8_t node_id)
{
    for (uint8_t k = 0; k < ASM_SERIAL_BYTES; k++)
        c->serial[k] = serial[k];
    c->node_id = node_id;
    c->position = ASM_NOT_SCANNING;
    c->muted = 0;
}

/* The identifier's fields by mask, not asm_can_unpack: this runs on every frame a module receives. */
#define FIELD(value, name) ((uint32_t)(value) << ASM_CAN_##name##_SHIFT)
#define COMMAND_MASK (FIELD(ASM_CAN_DEST_KIND_MASK, DEST_KIND) | FIELD(ASM_CAN_DEST_MASK, DEST) | FIELD(ASM_CAN_FRAME_MASK, FRAME))

int asm_commission_is_command(uint32_t id)
{
    return (id & COMMAND_MASK) == (FIELD(ASM_DEST_SYSTEM, DEST_KIND) | FIELD(ASM_SYSTEM_COMMISSION, DEST));
}

static int answer_with(uint32_t *answer, uint8_t kind, uint8_t value, uint8_t position)
{
    *answer = FIELD(ASM_PRIORITY_REPLY, PRIORITY) | FIELD(ASM_DEST_SYSTEM, DEST_KIND) |
              FIELD(ASM_SYSTEM_COMMISSIONED, DEST) | FIELD(value, SOURCE) | FIELD(kind << POSITION_BITS | position, COUNTER);
    return 1;
}

/* What a module in the scan answers at its position: its serial's byte there, or FOUND past the last. */
static int answer_position(const struct asm_commission *c, uint32_t *answer)
{
    if (c->position >= ASM_SERIAL_BYTES)
        return answer_with(answer, ASM_COMMISSIONED_FOUND, c->node_id, 0);
    return answer_with(answer, ASM_COMMISSIONED_BYTE, c->serial[c->position], c->position);
}

static int in_scope(const struct asm_commission *c, uint8_t scope, uint8_t node_id)
{
    if (scope == ASM_SCOPE_UNCONFIGURED)
        return c->node_id == ASM_UNCONFIGURED;
    if (scope == ASM_SCOPE_NODE_ID)
        return c->node_id == node_id;
    return scope == ASM_SCOPE_EVERY;
}

int asm_commission_command(struct asm_commission *c, const uint8_t *data, uint8_t dlc, asm_commission_store store,
                           void *ctx, uint32_t *answer)
{
    if (dlc == 0)
        return 0;
    uint8_t op = data[0], found = c->position == ASM_SERIAL_BYTES;
    if (op == ASM_COM_SCAN && dlc >= 2) {
        int joins = !c->muted && in_scope(c, data[1], dlc >= 3 ? data[2] : 0);
        if (data[1] == ASM_SCOPE_NODE_ID && dlc < 3)
            joins = 0;
        c->position = joins ? 0 : ASM_NOT_SCANNING;
        return joins ? answer_position(c, answer) : 0;
    }
    if (op == ASM_COM_NARROW && dlc >= 3 && c->position != ASM_NOT_SCANNING) {
        uint8_t at = data[1], byte = data[2];
        if (at < ASM_SERIAL_BYTES && c->serial[at] == byte && (c->position == at || c->position == at + 1)) {
            c->position = (uint8_t)(at + 1); /* moved on now, or already (a repeated command): the same answer */
            return answer_position(c, answer);
        }
        c->position = ASM_NOT_SCANNING;
        return 0;
    }
    if (op == ASM_COM_ASSIGN && dlc >= 2 && found) {
        uint8_t node_id = data[1];
        if (node_id == 0xFFu || (store != 0 && store(ctx, node_id) != 0))
            return 0; /* not a node ID, or not stored: no answer, the tool asks again */
        c->node_id = node_id;
        return answer_with(answer, ASM_COMMISSIONED_ASSIGNED, node_id, 0);
    }
    if (op == ASM_COM_MUTE && found) {
        c->muted = 1;
        return answer_with(answer, ASM_COMMISSIONED_MUTED, c->node_id, 0);
    }
    if (op == ASM_COM_UNMUTE) {
        c->muted = 0;
        c->position = ASM_NOT_SCANNING;
    }
    return 0;
}
