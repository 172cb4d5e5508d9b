/* The STM32F4 flash controller (RM0090 §3) and the boot log the bootloader and the image share (docs/protocol.md
 * §12): erase a sector, program words, write-protect sectors, and the log's records of each slot. */
#ifndef ASM_STM32F4_FLASH_H
#define ASM_STM32F4_FLASH_H

#include <stdint.h>

#include "stm32f4_layout.h"

/* The log's record kinds (byte 1 of a record's first word). */
enum { LOG_ERASED = 1, LOG_INSTALLED = 2, LOG_TRIED = 3, LOG_CONFIRMED = 4 };

/* A slot as the log tells it: ``recorded`` 0 is a slot the log never named (the probe's image, generation 0). */
struct slot_state {
    uint32_t generation;
    uint8_t recorded, erased, tried, confirmed;
};

/* Unlock, erase one sector, lock: 0 or FLASH_SR's error flags. */
uint32_t flash_erase_sector(uint32_t sector);
/* Unlock, program ``count`` words at ``address`` (erased words), lock: 0 or the error flags. */
uint32_t flash_program_words(uint32_t address, const uint32_t *words, uint32_t count);
/* Write-protect (option bytes nWRP) exactly the sectors of ``mask`` (bit n: sector n), if they differ. */
void flash_protect(uint32_t mask);
/* Both slots' states from the log. */
void boot_log_read(struct slot_state slots[2]);
/* Append a record (a full log is erased and the slots' state written again first): 0, or the error flags. */
uint32_t boot_log_append(uint32_t kind, uint32_t slot, uint32_t generation);
/* The slot holds a whole image: magic, header version and size, size, load address, CRC. */
int image_valid(uint32_t slot);

#endif
