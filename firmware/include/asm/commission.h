/* Commissioning (docs/protocol.md section 7, "Commissioning"): a module's side, as asm_py/canbus/commission.py's
 * Commissionee. A module without a node ID answers nothing but these commands; a tool finds it by its serial (an
 * STM32's 96-bit unique ID), a byte per round trip, and assigns it an ID, which the port stores in flash. */
#ifndef ASM_COMMISSION_H
#define ASM_COMMISSION_H

#include <stdint.h>

#include "asm/contract.h"

#define ASM_NOT_SCANNING 0xFFu

struct asm_commission {
    uint8_t serial[ASM_SERIAL_BYTES];
    uint8_t node_id;  /* ASM_UNCONFIGURED: none */
    uint8_t position; /* where the scan has come; ASM_SERIAL_BYTES: this module is the found one; ASM_NOT_SCANNING */
    uint8_t muted;
};

/* Stores ``node_id`` in non-volatile memory: 0 when it is stored (then the module answers ASSIGNED), else not. */
typedef int (*asm_commission_store)(void *ctx, uint8_t node_id);

void asm_commission_init(struct asm_commission *c, const uint8_t *serial, uint8_t node_id);
/* The frame identifier ``id`` is a COMMISSION command (a system frame with that code, single). */
int asm_commission_is_command(uint32_t id);
/* Handle the data of one command: 1 with ``*answer`` (the 29-bit identifier of the COMMISSIONED frame to send, no
 * data) when the module answers, 0 when it stays silent. */
int asm_commission_command(struct asm_commission *c, const uint8_t *data, uint8_t dlc, asm_commission_store store,
                           void *ctx, uint32_t *answer);

#endif
