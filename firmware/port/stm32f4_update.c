/* Firmware update over the bus, the image's side (stm32f4_update.h, docs/protocol.md §12). The image is written to
 * the slot the bootloader did not start (write-protected: the running one's sectors refuse), checked whole at
 * firmware.install, and booted on trial at the reset that follows. */
#include "stm32f4_update.h"

#include <string.h>

#include "asm/module.h"
#include "asm/profile.h"
#include "asm/version.h"
#include "asm/wire.h"
#include "stm32f4_flash.h"

#define REG(address) (*(volatile uint32_t *)(address))
#define IWDG_KR REG(0x40003000u)
#define SCB_AIRCR REG(0xE000ED0Cu)

/* The header the image builder (asm_module/firmware_image.py) completes with the size and the CRC. */
__attribute__((section(".image_header"), used)) const struct image_header image_header = {
    ASM_IMAGE_MAGIC, 0, ASM_IMAGE_HEADER_VERSION, ASM_IMAGE_HEADER_SIZE, ASM_FW_VERSION, 0, LAYOUT_IMAGE_RAM, {0}};

static const uint8_t D_IMAGE[] = {ASM_D_FIRMWARE_IMAGE}, D_INSTALL[] = {ASM_D_FIRMWARE_INSTALL},
                     D_STATUS[] = {ASM_D_FIRMWARE_STATUS};
static struct asm_object image, install, status;
static uint32_t slot, generation, trial, confirmed, received, install_crc, reset_at, resetting, fed_at;
static uint8_t status_v[13]; /* record{state:uint8,running:uint32,other:uint32,received:uint32} */

static uint32_t other(void) { return slot ^ 1u; }

/* While the module's gait runs nothing of an update is taken: erasing the slot stalls the control loop (one flash
 * bank: instruction fetches wait for the erase), and the install's reset would drop the joint mid-step. The update
 * tool checks this first and holds every module's gait.lease against deploys; this is the guard against a gait
 * started without a lease (a group start) while the update streams. */
static int gait_runs(struct asm_node *node) { return asm_module_of(node)->gait.service.running != 0; }

static void report(uint32_t state)
{
    const struct image_header *h = (const struct image_header *)LAYOUT_SLOT_ADDRESS(other());
    uint32_t version = h->magic == ASM_IMAGE_MAGIC ? h->version : 0xFFFFFFFFu, running = ASM_FW_VERSION;
    status_v[0] = (uint8_t)state;
    memcpy(status_v + 1, &running, 4);
    memcpy(status_v + 5, &version, 4);
    memcpy(status_v + 9, &received, 4);
}

void update_boot(void)
{
    struct slot_state slots[2], *o;
    if (BOOT_INFO->magic == BOOT_INFO_MAGIC) {
        slot = BOOT_INFO->slot & 1u;
        generation = BOOT_INFO->generation;
        trial = BOOT_INFO->trial;
    }
    confirmed = !trial;
    boot_log_read(slots);
    o = &slots[other()];
    if (o->erased)
        report(ASM_FW_INTERRUPTED); /* erased for an update that never installed: a reset cut it */
    else if (o->recorded && o->tried && !o->confirmed && o->generation > generation)
        report(ASM_FW_ROLLED_BACK);
    else
        report(trial ? ASM_FW_TRIAL : ASM_FW_IDLE);
}

static int set_image(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    uint32_t offset, words[ASM_IMAGE_CHUNK / 4u], errors = 0;
    (void)o;
    if (node->estop)
        return ASM_S_ESTOP; /* an update ends in a reset, which would release the latch: refused, as any move */
    if (gait_runs(node))
        return ASM_S_LOCKED;
    if (length < 4u || (length - 4u) % 4u || length - 4u > ASM_IMAGE_CHUNK || resetting)
        return ASM_S_VALUE_ERROR;
    memcpy(&offset, data, 4);
    if (offset != (offset ? received : 0u))
        return ASM_S_VALUE_ERROR; /* in order: the next bytes, or a new image from 0 */
    if (offset + (length - 4u) > LAYOUT_IMAGE_MAX)
        return ASM_S_TOO_LARGE;
    if (offset == 0) { /* a new image: the slot is no longer one to boot, then erased */
        received = 0;
        errors = boot_log_append(LOG_ERASED, other(), 0);
        if (!errors)
            errors = flash_erase_sector(LAYOUT_SLOT_SECTOR(other()));
    }
    memcpy(words, data + 4, length - 4u);
    if (!errors)
        errors = flash_program_words(LAYOUT_SLOT_ADDRESS(other()) + offset, words, (uint32_t)(length - 4u) / 4u);
    if (errors) {
        report(ASM_FW_FLASH_ERROR);
        return ASM_S_INTERNAL;
    }
    received = offset + (uint32_t)(length - 4u);
    report(ASM_FW_RECEIVING);
    return ASM_S_OK;
}

static int set_install(struct asm_node *node, struct asm_object *o, const uint8_t *data, size_t length)
{
    const struct image_header *h = (const struct image_header *)LAYOUT_SLOT_ADDRESS(other());
    (void)o;
    if (node->estop)
        return ASM_S_ESTOP; /* latched after the image was written: no reset into it until released */
    if (gait_runs(node))
        return ASM_S_LOCKED; /* a gait started after the image was written: no reset under it */
    if (length != 4u || resetting)
        return ASM_S_VALUE_ERROR;
    memcpy(&install_crc, data, 4);
    if (received == 0 || h->size != received || h->crc != install_crc || !image_valid(other())) {
        report(ASM_FW_REFUSED);
        return ASM_S_VALUE_ERROR;
    }
    if (boot_log_append(LOG_INSTALLED, other(), generation + 1u)) {
        report(ASM_FW_FLASH_ERROR);
        return ASM_S_INTERNAL;
    }
    report(ASM_FW_INSTALLED);
    resetting = 1;
    asm_module_of(node)->reset_pending = 1; /* and from now no gait starts (gait.c): none runs into the reset */
    reset_at = node->now_ms + ASM_RESET_DELAY_MS;
    return ASM_S_OK;
}

void update_register(struct asm_node *node)
{
    asm_object_init(&image, "firmware.image", ASM_C_FIRMWARE_IMAGE, ASM_ATTRIBUTE, D_IMAGE, sizeof D_IMAGE, &received,
                    4, 4 + ASM_IMAGE_CHUNK); /* a GET: the bytes written; a SET is never stored, only written */
    image.set = set_image;
    asm_object_init(&install, "firmware.install", ASM_C_FIRMWARE_INSTALL, ASM_ATTRIBUTE, D_INSTALL, sizeof D_INSTALL,
                    &install_crc, 4, 4);
    install.set = set_install;
    asm_object_init(&status, "firmware.status", ASM_C_FIRMWARE_STATUS, ASM_ATTRIBUTE, D_STATUS, sizeof D_STATUS,
                    status_v, sizeof status_v, sizeof status_v);
    status.flags = ASM_F_READ_ONLY;
    asm_node_register(node, &image);
    asm_node_register(node, &install);
    asm_node_register(node, &status);
}

void update_poll(uint32_t now_ms)
{
    if (!confirmed) { /* on the bus, its node running: this image works */
        confirmed = !boot_log_append(LOG_CONFIRMED, slot, generation);
        if (confirmed)
            report(ASM_FW_CONFIRMED);
    }
    if (confirmed && now_ms - fed_at >= 100u) { /* well within the watchdog's ASM_CONFIRM_MS */
        IWDG_KR = 0xAAAAu;
        fed_at = now_ms;
    }
    if (resetting && (int32_t)(now_ms - reset_at) >= 0)
        SCB_AIRCR = 0x05FA0004u; /* SYSRESETREQ: into the bootloader */
}
