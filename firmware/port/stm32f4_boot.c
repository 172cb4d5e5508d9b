/* The example board's bootloader (docs/protocol.md §12), sector 0: choose the image to run from the two slots and
 * the boot log, write-protect it, start the watchdog, copy it into RAM and jump to it.
 *
 * Of the slots holding a whole image (header and CRC-32, checked on the copy in RAM that runs), the highest
 * generation that is confirmed or was never tried runs; one never tried runs on trial (TRIED is logged first), and the image must
 * confirm itself before the independent watchdog (ASM_CONFIRM_MS) resets the board, or the next boot finds it tried
 * and unconfirmed and runs the older one. No image at all: the board waits for a probe. */
#include <stdint.h>

#include "asm/profile.h"
#include "asm/wire.h"
#include "stm32f4_flash.h"

#define REG(address) (*(volatile uint32_t *)(address))
#define IWDG_KR REG(0x40003000u)
#define IWDG_PR REG(0x40003004u)
#define IWDG_RLR REG(0x40003008u)
#define SCB_VTOR REG(0xE000ED08u)
#define LSI_HZ 32000u
#define IWDG_DIVIDER 256u /* PR 6 */

/* The header of the image in ``slot`` is this bootloader's and its size fits the RAM. */
static uint32_t header_size(uint32_t slot)
{
    const struct image_header *h = (const struct image_header *)LAYOUT_SLOT_ADDRESS(slot);
    if (h->magic != ASM_IMAGE_MAGIC || h->header_version != ASM_IMAGE_HEADER_VERSION ||
        h->header_size != ASM_IMAGE_HEADER_SIZE || h->load_address != LAYOUT_IMAGE_RAM || h->size % 4u ||
        h->size <= ASM_IMAGE_HEADER_SIZE || h->size > LAYOUT_IMAGE_MAX)
        return 0;
    return h->size;
}

/* Copy the image of ``slot`` into RAM and check its CRC-32 there (what runs is what was checked): 1 if whole. */
static int load(uint32_t slot)
{
    uint32_t size = header_size(slot);
    const uint32_t *from = (const uint32_t *)LAYOUT_SLOT_ADDRESS(slot);
    uint32_t *to = (uint32_t *)LAYOUT_IMAGE_RAM;
    if (!size)
        return 0;
    for (uint32_t k = 0; k < size / 4u; k++)
        to[k] = from[k];
    return asm_crc32((const uint8_t *)to + 8, size - 8u) == to[1];
}

/* Load the image to boot (-1: none) and say its slot, generation and trial: the highest generation that is
 * confirmed or never tried, of the slots whose image is whole. */
static int choose(uint32_t *generation, uint32_t *trial)
{
    struct slot_state slots[2];
    uint32_t eligible[2], gen[2];
    boot_log_read(slots);
    for (uint32_t s = 0; s < 2; s++) {
        const struct slot_state *st = &slots[s];
        gen[s] = st->recorded ? st->generation : 0u;
        /* not erased for an update that never installed, nor tried and never confirmed (rolled back) */
        eligible[s] = !st->erased && !(st->recorded && st->tried && !st->confirmed);
    }
    for (uint32_t k = 0; k < 2; k++) {
        uint32_t s = (gen[1] > gen[0]) ^ k; /* the newer first */
        if (eligible[s] && load(s)) {
            *generation = gen[s];
            *trial = slots[s].recorded && !slots[s].confirmed;
            return (int)s;
        }
    }
    return -1;
}

static void watchdog_start(void)
{
    IWDG_KR = 0x5555u; /* PR and RLR writable */
    IWDG_PR = 6u;
    IWDG_RLR = ASM_CONFIRM_MS * (LSI_HZ / 1000u) / IWDG_DIVIDER;
    IWDG_KR = 0xAAAAu;
    IWDG_KR = 0xCCCCu; /* started: nothing stops it */
}

__attribute__((noreturn)) static void jump(uint32_t vectors)
{
    SCB_VTOR = vectors;
    uint32_t stack = ((const uint32_t *)vectors)[0], entry = ((const uint32_t *)vectors)[1];
    __asm__ volatile("msr msp, %0\n bx %1" : : "r"(stack), "r"(entry) : "memory");
    __builtin_unreachable();
}

int main(void)
{
    uint32_t generation = 0, trial = 0;
    int slot = choose(&generation, &trial);
    if (slot < 0)
        for (;;) /* nothing to run: a probe must flash an image */
            ;
    if (trial)
        boot_log_append(LOG_TRIED, (uint32_t)slot, generation);
    flash_protect(1u << 0 | 1u << 1 | 1u << LAYOUT_SLOT_SECTOR((uint32_t)slot));
    watchdog_start();
    BOOT_INFO->magic = BOOT_INFO_MAGIC;
    BOOT_INFO->slot = (uint32_t)slot;
    BOOT_INFO->generation = generation;
    BOOT_INFO->trial = trial;
    jump(LAYOUT_IMAGE_RAM + ASM_IMAGE_HEADER_SIZE);
}

extern uint32_t _stack_top;
void Reset_Handler(void) { main(); }
void Default_Handler(void) { for (;;) ; }
__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))(uintptr_t)&_stack_top, Reset_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, 0, 0, 0, 0, Default_Handler, Default_Handler, 0, Default_Handler,
    Default_Handler};
