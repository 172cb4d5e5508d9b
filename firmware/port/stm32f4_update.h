/* Firmware update over the bus, the image's side (docs/protocol.md §12): the image header, firmware.image,
 * firmware.install and firmware.status, confirming a trial boot and feeding the watchdog. */
#ifndef ASM_STM32F4_UPDATE_H
#define ASM_STM32F4_UPDATE_H

#include <stdint.h>

#include "asm/node.h"

/* At boot, before the node runs: what the bootloader started and what the log says of the other slot. */
void update_boot(void);
/* Register the update objects on ``node`` (after asm_module_init). */
void update_register(struct asm_node *node);
/* Every pass of the main loop, once the CAN controller is on the bus: confirm a trial image, feed the watchdog once
 * confirmed, reset when an installed image is due. */
void update_poll(uint32_t now_ms);

#endif
