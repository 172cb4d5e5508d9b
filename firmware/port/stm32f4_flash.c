/* The flash controller and the boot log (stm32f4_flash.h), shared by the bootloader and the image. */
#include "stm32f4_flash.h"

#include "asm/profile.h"
#include "asm/wire.h"

#define REG(address) (*(volatile uint32_t *)(address))
#define FLASH_KEYR REG(0x40023C04u)
#define FLASH_OPTKEYR REG(0x40023C08u)
#define FLASH_SR REG(0x40023C0Cu)
#define FLASH_CR REG(0x40023C10u)
#define FLASH_OPTCR REG(0x40023C14u)
#define SR_BSY (1u << 16)
#define SR_ERRORS 0xF2u
#define CR_LOCK (1u << 31)
#define PSIZE_X32 (2u << 8)
#define LOG ((const volatile uint32_t *)LAYOUT_LOG_ADDRESS)
#define LOG_WORDS (LAYOUT_LOG_BYTES / 4u)
#define LOG_MAGIC 0xB0070000u
#define LOG_RECORD(kind, slot) (LOG_MAGIC | (kind) << 8 | (slot))

static void wait(void)
{
    while (FLASH_SR & SR_BSY)
        ;
}

static void unlock(void)
{
    if (FLASH_CR & CR_LOCK) {
        FLASH_KEYR = 0x45670123u;
        FLASH_KEYR = 0xCDEF89ABu;
    }
    FLASH_SR = 0xF3u; /* clear EOP and the error flags of an earlier operation */
}

static uint32_t lock(void)
{
    uint32_t errors = FLASH_SR & SR_ERRORS;
    FLASH_CR = CR_LOCK;
    return errors;
}

uint32_t flash_erase_sector(uint32_t sector)
{
    unlock();
    wait();
    FLASH_CR = PSIZE_X32 | (sector << 3) | 2u; /* SNB, SER */
    FLASH_CR |= 1u << 16;                      /* STRT */
    wait();
    return lock();
}

/* RM0090 3.6.2: BSY clear, PG set, the data writes — all the words with PG held (a write while the previous one is
 * still being programmed stalls the bus until it is done), no status read between — then BSY clear again and the
 * error flags of them all (what refuses one word, a lock, a protected sector, refuses the ones after it too). */
uint32_t flash_program_words(uint32_t address, const uint32_t *words, uint32_t count)
{
    unlock();
    wait();
    FLASH_CR = PSIZE_X32 | 1u; /* PG */
    for (uint32_t k = 0; k < count; k++)
        ((volatile uint32_t *)address)[k] = words[k];
    wait();
    return lock();
}

void flash_protect(uint32_t mask)
{
    uint32_t wanted = (~mask & 0xFFFu) << 16; /* nWRP: 0 protects */
    if ((FLASH_OPTCR & (0xFFFu << 16)) == wanted)
        return; /* option bytes wear: written only when they change */
    FLASH_OPTKEYR = 0x08192A3Bu;
    FLASH_OPTKEYR = 0x4C5D6E7Fu;
    wait();
    FLASH_OPTCR = (FLASH_OPTCR & ~(0xFFFu << 16) & ~3u) | wanted;
    FLASH_OPTCR |= 2u; /* OPTSTRT */
    wait();
    FLASH_OPTCR |= 1u; /* OPTLOCK */
}

/* The first free record (both words erased): a record cut by a reset (its generation programmed, its first word
 * not) is skipped, never reused. */
static uint32_t log_end(void)
{
    uint32_t k = 0;
    while (k < LOG_WORDS && (LOG[k] & LOG[k + 1]) != 0xFFFFFFFFu)
        k += 2;
    return k;
}

void boot_log_read(struct slot_state slots[2])
{
    for (uint32_t s = 0; s < 2; s++)
        slots[s] = (struct slot_state){0, 0, 0, 0, 0};
    for (uint32_t k = 0, end = log_end(); k < end; k += 2) {
        uint32_t head = LOG[k], generation = LOG[k + 1], kind = head >> 8 & 0xFFu, slot = head & 0xFFu;
        if ((head & 0xFFFF0000u) != LOG_MAGIC || slot > 1)
            continue; /* a cut record */
        struct slot_state *s = &slots[slot];
        if (kind == LOG_ERASED || kind == LOG_INSTALLED)
            *s = (struct slot_state){generation, 1, kind == LOG_ERASED, 0, 0};
        else if (kind == LOG_TRIED && !s->erased && s->recorded && generation == s->generation)
            s->tried = 1;
        else if (kind == LOG_CONFIRMED && !s->erased && s->recorded && generation == s->generation)
            s->confirmed = 1;
    }
}

static uint32_t put(uint32_t at, uint32_t kind, uint32_t slot, uint32_t generation)
{
    uint32_t errors = flash_program_words(LAYOUT_LOG_ADDRESS + 4u * (at + 1u), &generation, 1);
    uint32_t head = LOG_RECORD(kind, slot);
    return errors ? errors : flash_program_words(LAYOUT_LOG_ADDRESS + 4u * at, &head, 1);
}

uint32_t boot_log_append(uint32_t kind, uint32_t slot, uint32_t generation)
{
    uint32_t at = log_end(), errors = 0;
    if (at + 2u > LOG_WORDS) { /* full (with room kept for the state): erase, write the state again */
        struct slot_state slots[2];
        boot_log_read(slots);
        errors = flash_erase_sector(LAYOUT_LOG_SECTOR);
        at = 0;
        for (uint32_t s = 0; s < 2 && !errors; s++) {
            if (!slots[s].recorded)
                continue;
            errors = put(at, slots[s].erased ? LOG_ERASED : LOG_INSTALLED, s, slots[s].generation);
            at += 2;
            if (!errors && slots[s].tried)
                errors = put(at, LOG_TRIED, s, slots[s].generation), at += 2;
            if (!errors && slots[s].confirmed)
                errors = put(at, LOG_CONFIRMED, s, slots[s].generation), at += 2;
        }
    }
    return errors ? errors : put(at, kind, slot, generation);
}

int image_valid(uint32_t slot)
{
    const struct image_header *h = (const struct image_header *)LAYOUT_SLOT_ADDRESS(slot);
    uint32_t size = h->size;
    if (h->magic != ASM_IMAGE_MAGIC || h->header_version != ASM_IMAGE_HEADER_VERSION ||
        h->header_size != ASM_IMAGE_HEADER_SIZE || h->load_address != LAYOUT_IMAGE_RAM || size % 4u ||
        size <= ASM_IMAGE_HEADER_SIZE || size > LAYOUT_IMAGE_MAX)
        return 0;
    return asm_crc32((const uint8_t *)h + 8, size - 8u) == h->crc;
}
