/* The example board's flash and RAM as the bootloader and the image share them (docs/protocol.md §12): which sector
 * holds what, where an image runs, and what the bootloader tells the image it started. The linker scripts
 * (stm32f4_boot.ld, stm32f4.ld) place the same addresses. */
#ifndef ASM_STM32F4_LAYOUT_H
#define ASM_STM32F4_LAYOUT_H

#include <stdint.h>

#define LAYOUT_BOARD_ADDRESS 0x08004000u /* sector 1: board_config, written by the probe */
#define LAYOUT_LOG_ADDRESS 0x08008000u   /* sector 2: the boot log */
#define LAYOUT_LOG_SECTOR 2u
#define LAYOUT_LOG_BYTES 0x4000u
#define LAYOUT_SLOT_ADDRESS(slot) ((slot) ? 0x08040000u : 0x08020000u) /* sectors 5 and 6 */
#define LAYOUT_SLOT_SECTOR(slot) ((slot) ? 6u : 5u)
#define LAYOUT_IMAGE_RAM 0x20000000u /* where an image runs: the bootloader copies it here */
#define LAYOUT_IMAGE_MAX 0x10000u    /* 64 KiB: the RAM an image runs from */

/* What the bootloader leaves for the image in the top 16 bytes of RAM (below the image's stack). */
struct boot_info {
    uint32_t magic; /* BOOT_INFO_MAGIC: written by the bootloader at this boot */
    uint32_t slot;  /* 0 (A) or 1 (B) */
    uint32_t generation; /* the slot's generation in the boot log (0: the probe's image) */
    uint32_t trial;      /* 1: the image runs on trial and must confirm itself */
};
#define BOOT_INFO ((volatile struct boot_info *)0x2001FFF0u)
#define BOOT_INFO_MAGIC 0x544F4F42u /* "BOOT" */

/* The image header's fields (docs/protocol.md §12), at the start of a slot and of the image in RAM. */
struct image_header {
    uint32_t magic, crc;
    uint16_t header_version, header_size;
    uint32_t version, size, load_address;
    uint8_t reserved[104];
};

#endif
