/* An example port: one module on an STM32F4 (Cortex-M4) with its bxCAN peripheral, compiled by bench/firmware.py
 * to measure flash and RAM, and run unchanged, instruction by instruction, by asm_module/emulated.py (Unicorn, with
 * models of the peripherals below). What a board adds to the portable runtime is exactly this file: a millisecond
 * clock, frames in and out of the CAN controller, and the joint: a servo's PWM on TIM3 channel 1 (PA6), a quadrature
 * encoder on TIM2 (PA0/PA1 in encoder mode) and a foot switch on PA2.
 *
 * Registers are those of RM0090 (STM32F405/407) for CAN1; no vendor headers are needed. The bus is set up for
 * 1 Mbit/s from a 42 MHz APB1 clock, extended identifiers, one acceptance filter per rule of
 * docs/protocol.md section 7 ("a module passes only what it must act on"). */
#include <stdint.h>

#include "asm/commission.h"
#include "asm/module.h"
#include "asm/wire.h"
#include "stm32f4_update.h"

#define REG(address) (*(volatile uint32_t *)(address))
#define CAN1 0x40006400u
#define CAN_MCR REG(CAN1 + 0x000u)
#define CAN_MSR REG(CAN1 + 0x004u)
#define CAN_TSR REG(CAN1 + 0x008u)
#define CAN_RF0R REG(CAN1 + 0x00Cu)
#define CAN_BTR REG(CAN1 + 0x01Cu)
#define CAN_TIR(m) REG(CAN1 + 0x180u + 0x10u * (m))
#define CAN_TDTR(m) REG(CAN1 + 0x184u + 0x10u * (m))
#define CAN_TDLR(m) REG(CAN1 + 0x188u + 0x10u * (m))
#define CAN_TDHR(m) REG(CAN1 + 0x18Cu + 0x10u * (m))
#define CAN_RI0R REG(CAN1 + 0x1B0u)
#define CAN_RDT0R REG(CAN1 + 0x1B4u)
#define CAN_RDL0R REG(CAN1 + 0x1B8u)
#define CAN_RDH0R REG(CAN1 + 0x1BCu)
#define CAN_FMR REG(CAN1 + 0x200u)
#define CAN_FM1R REG(CAN1 + 0x204u)
#define CAN_FS1R REG(CAN1 + 0x20Cu)
#define CAN_FFA1R REG(CAN1 + 0x214u)
#define CAN_FA1R REG(CAN1 + 0x21Cu)
#define CAN_FR1(f) REG(CAN1 + 0x240u + 8u * (f))
#define CAN_FR2(f) REG(CAN1 + 0x244u + 8u * (f))
#define SYST_CSR REG(0xE000E010u)
#define SYST_RVR REG(0xE000E014u)
#define SYST_CVR REG(0xE000E018u)
#define SCB_ICSR REG(0xE000ED04u)   /* PENDSTSET (bit 26): SysTick's interrupt is pending */
#define SCB_CPACR REG(0xE000ED88u)
#define DEMCR REG(0xE000EDFCu)      /* TRCENA (bit 24) powers the DWT */
#define DWT_CTRL REG(0xE0001000u)   /* CYCCNTENA (bit 0) */
#define DWT_CYCCNT REG(0xE0001004u) /* the core's cycle counter: what module.info's tick_cycles counts */
#define RCC_AHB1ENR REG(0x40023830u)
#define RCC_APB1ENR REG(0x40023840u)
#define TIM2 0x40000000u /* the encoder: 32 bits, counting both edges of both channels */
#define TIM3 0x40000400u /* the servo's PWM */
#define TIM_CR1(t) REG((t) + 0x00u)
#define TIM_SMCR(t) REG((t) + 0x08u)
#define TIM_CCMR1(t) REG((t) + 0x18u)
#define TIM_CCER(t) REG((t) + 0x20u)
#define TIM_CNT(t) REG((t) + 0x24u)
#define TIM_PSC(t) REG((t) + 0x28u)
#define TIM_ARR(t) REG((t) + 0x2Cu)
#define TIM_CCR1(t) REG((t) + 0x34u)
#define GPIOA_IDR REG(0x40020010u)
#define FLASH_KEYR REG(0x40023C04u)
#define FLASH_SR REG(0x40023C0Cu)
#define FLASH_CR REG(0x40023C10u)
#define UID ((const volatile uint8_t *)0x1FFF7A10u) /* the 96-bit unique ID: the module's serial */

#define CONTROL_MS 20u       /* the gait tick: 50 Hz */
#define CYCLES_PER_MS 168000u /* the core clock, 168 MHz */
#define ENCODER_COUNTS 4096  /* per turn (1,024 lines, both edges of both channels) */
#define PWM_CENTRE_US 1500.0f /* the servo's pulse at 0 degrees; 1,000 us more at +90 */
#define MODULE_TYPE "stm32f4-servo" /* module.type: what this board is, as a gait's [robot.types.NAME] names it */

/* What differs between modules of one robot, written by the probe in flash sector 1 (stm32f4.ld; the emulator writes
 * it as a flasher would), never part of an image an update carries: volatile, so the compiler reads it rather than
 * folding the defaults in. */
struct board_config {
    uint8_t node_id;
    char name[15];
    float hardware_min, hardware_max;
};
__attribute__((section(".board_config"), used)) static const volatile struct board_config board_config = {7, "m7", -90.0f, 90.0f};

static struct asm_module module;
static volatile uint32_t milliseconds; /* at SysTick's last interrupt: a multiple of CONTROL_MS (now_ms() between) */
static struct asm_commission commission;
static uint8_t configured; /* the module runs its node (else it answers only commissioning) */
static char node_name[8];  /* "m<ID>" of a commissioned module */

/* The settings: flash sector 11 (128 KiB at 0x080E0000, kept out of the image by the linker script), a log of 8-byte
 * records appended by programming erased words; the last one holds. A full sector is erased and the log starts
 * again: a sector endures 10,000 erases, so a module can be renumbered 160 million times. */
#define SETTINGS ((const volatile uint32_t *)0x080E0000u)
#define SETTINGS_SECTOR 11u
#define SETTINGS_WORDS (0x20000u / 4u)
#define RECORD_MAGIC 0x41534D31u /* "ASM1" */
#define ID_RECORD(id) (0xA55A0000u | (uint32_t)(uint8_t)~(id) << 8 | (id))
/* A calibration record takes three slots: CALIBRATION_MAGIC, zero, min, max, CALIBRATION_TAG | direction, and the
 * CRC-32 of the four words between; programmed from the second word on, the magic last, so a reset in the middle
 * leaves words no reader takes for a record (a slot's first word is never all ones: zero is not NaN). */
#define CALIBRATION_MAGIC 0x41534D43u /* "ASMC" */
#define CALIBRATION_TAG 0xCA1B0000u
#define CALIBRATION_WORDS 6u

/* The stored node ID: 1 and ``*node_id`` if a record holds one (0: erased by the tool), 0 if none was ever stored. */
static int settings_node_id(uint8_t *node_id)
{
    int found = 0;
    for (uint32_t k = 0; k < SETTINGS_WORDS && (SETTINGS[k] & SETTINGS[k + 1]) != 0xFFFFFFFFu; k += 2) {
        uint32_t word = SETTINGS[k + 1];
        if (SETTINGS[k] == RECORD_MAGIC && word == ID_RECORD(word & 0xFFu)) { /* not a record cut by a reset */
            *node_id = (uint8_t)word;
            found = 1;
        }
    }
    return found;
}

/* The stored calibration: 1 and ``*c`` if a whole record holds one, 0 if none was ever stored. */
static int settings_calibration(struct asm_calibration *c)
{
    int found = 0;
    for (uint32_t k = 0; k + CALIBRATION_WORDS <= SETTINGS_WORDS && (SETTINGS[k] & SETTINGS[k + 1]) != 0xFFFFFFFFu;
         k += 2) {
        uint32_t w[4] = {SETTINGS[k + 1], SETTINGS[k + 2], SETTINGS[k + 3], SETTINGS[k + 4]};
        if (SETTINGS[k] != CALIBRATION_MAGIC || (w[3] & 0xFFFFFF00u) != CALIBRATION_TAG ||
            SETTINGS[k + 5] != asm_crc32((const uint8_t *)w, sizeof w))
            continue;
        float v[3];
        for (int j = 0; j < 3; j++) {
            union { uint32_t u; float f; } bits = {w[j]};
            v[j] = bits.f;
        }
        *c = (struct asm_calibration){v[0], (int8_t)(uint8_t)w[3], v[1], v[2]};
        found = 1;
    }
    return found;
}

static void flash_wait(void)
{
    while (FLASH_SR & (1u << 16)) /* BSY */
        ;
}

/* RM0090 3.6: unlock, erase a sector or program words (PSIZE x32), lock again. 0, or the error flags of FLASH_SR. */
static uint32_t flash_program(uint32_t address, uint32_t value)
{
    flash_wait();
    FLASH_CR = (2u << 8) | 1u; /* PSIZE x32, PG */
    *(volatile uint32_t *)address = value;
    flash_wait();
    FLASH_CR = 0;
    return FLASH_SR & 0xF2u;
}

static uint32_t flash_erase(uint32_t sector)
{
    flash_wait();
    FLASH_CR = (2u << 8) | (sector << 3) | 2u; /* PSIZE x32, SNB, SER */
    FLASH_CR |= 1u << 16;                      /* STRT */
    flash_wait();
    FLASH_CR = 0;
    return FLASH_SR & 0xF2u;
}

/* The words of a record: an ID record (2) or a calibration record (CALIBRATION_WORDS). */
static uint32_t id_record(uint32_t *w, uint8_t node_id)
{
    w[0] = RECORD_MAGIC;
    w[1] = ID_RECORD(node_id);
    return 2;
}

static uint32_t calibration_record(uint32_t *w, const struct asm_calibration *c)
{
    const float v[3] = {c->zero, c->min, c->max};
    w[0] = CALIBRATION_MAGIC;
    for (int j = 0; j < 3; j++) {
        union { float f; uint32_t u; } bits = {v[j]};
        w[1 + j] = bits.u;
    }
    w[4] = CALIBRATION_TAG | (uint8_t)c->direction;
    w[5] = asm_crc32((const uint8_t *)(w + 1), 16);
    return CALIBRATION_WORDS;
}

/* Program ``w`` (n words) at word ``k``: the first word (the magic) last. 0, or the error flags. */
static uint32_t program_record(uint32_t k, const uint32_t *w, uint32_t n)
{
    uint32_t errors = 0;
    for (uint32_t j = 1; j < n && !errors; j++)
        errors = flash_program((uint32_t)&SETTINGS[k + j], w[j]);
    if (!errors)
        errors = flash_program((uint32_t)&SETTINGS[k], w[0]);
    for (uint32_t j = 0; j < n && !errors; j++)
        errors = SETTINGS[k + j] != w[j];
    return errors;
}

/* Append a record to the log. A log without room for it starts again: the sector erased, the other settings it held
 * (the ID or the calibration that this record does not replace) written first, then the record; a reset in between
 * loses what was not yet rewritten. */
static int settings_append(const uint32_t *w, uint32_t n)
{
    uint32_t k = 0, errors = 0, kept[CALIBRATION_WORDS];
    while (k < SETTINGS_WORDS && (SETTINGS[k] & SETTINGS[k + 1]) != 0xFFFFFFFFu) /* the first erased slot */
        k += 2;
    FLASH_KEYR = 0x45670123u;
    FLASH_KEYR = 0xCDEF89ABu;
    FLASH_SR = 0xF3u; /* clear EOP and the error flags of an earlier operation */
    if (k + n > SETTINGS_WORDS) { /* the log is full: start it again */
        uint8_t node_id = ASM_UNCONFIGURED;
        struct asm_calibration calibration;
        int has_id = settings_node_id(&node_id), has_calibration = settings_calibration(&calibration);
        errors = flash_erase(SETTINGS_SECTOR);
        k = 0;
        if (!errors && has_id && w[0] != RECORD_MAGIC)
            errors = program_record(k, kept, id_record(kept, node_id)), k += 2;
        if (!errors && has_calibration && w[0] != CALIBRATION_MAGIC)
            errors = program_record(k, kept, calibration_record(kept, &calibration)), k += CALIBRATION_WORDS;
    }
    if (!errors)
        errors = program_record(k, w, n);
    FLASH_CR = 1u << 31; /* LOCK */
    return errors != 0;
}

static int store_node_id(void *ctx, uint8_t node_id)
{
    (void)ctx;
    uint32_t w[2];
    return settings_append(w, id_record(w, node_id));
}

static int store_calibration(void *ctx, const struct asm_calibration *c)
{
    (void)ctx;
    uint32_t w[CALIBRATION_WORDS];
    return settings_append(w, calibration_record(w, c));
}

/* SysTick interrupts once a control period, not every millisecond: nothing in the main loop is due between (the
 * control tick, the watchdog's feed and an update's reset are on its 20 ms grid), so the core is not interrupted 19
 * times in 20 for nothing. A frame's time is read from the counter between interrupts (now_ms). */
void SysTick_Handler(void) { milliseconds += CONTROL_MS; }

/* The millisecond count now: the last interrupt's and what SysTick has counted down since (read again if the
 * interrupt came meanwhile); a counter that has reloaded while its interrupt is still pending is a period on. */
static uint32_t now_ms(void)
{
    uint32_t ms, elapsed, pending;
    do {
        ms = milliseconds;
        elapsed = CONTROL_MS * CYCLES_PER_MS - 1u - SYST_CVR;
        pending = SCB_ICSR & (1u << 26);
    } while (ms != milliseconds);
    if (pending && elapsed < CONTROL_MS * CYCLES_PER_MS / 2u)
        ms += CONTROL_MS;
    return ms + elapsed / CYCLES_PER_MS;
}

/* One mask filter (32-bit, FIFO 0): extended identifier ``id`` under ``mask`` (bits 28-0). */
static void filter(uint32_t bank, uint32_t id, uint32_t mask)
{
    CAN_FA1R &= ~(1u << bank);
    CAN_FR1(bank) = (id << 3) | 4u; /* IDE */
    CAN_FR2(bank) = (mask << 3) | 4u;
    CAN_FA1R |= 1u << bank;
}

/* The acceptance filters of the node ID the module runs under (none: commissioning only). */
static void can_filters(void)
{
    CAN_FMR |= 1u;      /* filter init */
    CAN_FM1R = 0;       /* mask mode */
    CAN_FS1R = 0x3FFFu; /* 32-bit */
    CAN_FFA1R = 0;      /* FIFO 0 */
    filter(0, (uint32_t)ASM_DEST_NODE << 24 | (uint32_t)commission.node_id << 16, 0x03FF0000u); /* to this node */
    filter(1, ASM_PRIORITY_REQUEST << 26 | (uint32_t)ASM_DEST_BROADCAST << 24, 0x1F000000u); /* broadcast requests */
    filter(2, ASM_PRIORITY_BULK << 26 | (uint32_t)ASM_DEST_BROADCAST << 24, 0x1F000000u); /* ... fragmented (not publications) */
    filter(3, (uint32_t)ASM_DEST_SYSTEM << 24 | (uint32_t)ASM_SYSTEM_ESTOP << 16, 0x03FF0000u); /* the e-stop */
    filter(13, (uint32_t)ASM_DEST_SYSTEM << 24 | (uint32_t)ASM_SYSTEM_COMMISSION << 16, 0x03FF0000u); /* commissioning */
    if (!configured)
        CAN_FA1R &= ~0xFu; /* without a node ID: commissioning only (an e-stop has nothing to stop) */
    CAN_FMR &= ~1u;
}

static void can_init(void)
{
    CAN_MCR = 1u; /* initialization request */
    while (!(CAN_MSR & 1u))
        ;
    CAN_BTR = (1u << 24) | (4u << 20) | (12u << 16) | 2u; /* SJW 2, TS2 5, TS1 13, prescaler 3: 42 MHz / 3 / 14 */
    can_filters();
    CAN_MCR = 0; /* normal mode */
    while (CAN_MSR & 1u)
        ;
}

/* Banks 4.. pass the gait.state publications of the neighbours the program waits on: set again whenever the program
 * changes what it waits on (a new table, an activation), as asm_host_watch_changed tells the host port. */
static void watch_neighbours(void)
{
    uint8_t ids[ASM_MAX_NEIGHBOURS], n;
    if (!module.gait.run.watch_changed)
        return;
    module.gait.run.watch_changed = 0;
    n = asm_program_watched(&module, ids);
    CAN_FMR |= 1u;
    for (uint8_t k = 0; k < ASM_MAX_NEIGHBOURS; k++) {
        CAN_FA1R &= ~(1u << (4u + k));
        if (k < n) /* priority 4, broadcast, from that node: its publications */
            filter(4u + k, ASM_PRIORITY_PUBLICATION << 26 | (uint32_t)ASM_DEST_BROADCAST << 24 | (uint32_t)ids[k] << 8,
                   0x1FFFFF00u);
    }
    CAN_FMR &= ~1u;
}

static int can_send(void *ctx, uint32_t id, const uint8_t *data, uint8_t dlc)
{
    (void)ctx;
    uint32_t tsr = CAN_TSR, box;
    if (!(tsr & (7u << 26)))
        return 1; /* no empty mailbox: the caller counts it */
    box = (tsr >> 24) & 3u;
    uint8_t b[8] = {0};
    for (uint8_t k = 0; k < dlc && k < 8; k++)
        b[k] = data[k];
    CAN_TDTR(box) = dlc;
    CAN_TDLR(box) = (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
    CAN_TDHR(box) = (uint32_t)b[4] | (uint32_t)b[5] << 8 | (uint32_t)b[6] << 16 | (uint32_t)b[7] << 24;
    CAN_TIR(box) = (id << 3) | 4u | 1u; /* extended, transmit request */
    return 0;
}

static void boot_node(void);

/* A commissioning command: answered (an ASSIGN once the ID is in flash), and a new ID run under at once. */
static void commissioning(const uint8_t *data, uint8_t dlc)
{
    uint8_t before = commission.node_id;
    uint32_t answer;
    if (asm_commission_command(&commission, data, dlc, store_node_id, 0, &answer))
        can_send(0, answer, 0, 0);
    if (commission.node_id != before) {
        if (configured)
            asm_node_leave(&module.node);
        boot_node();
    }
}

static void can_receive(void)
{
    while (CAN_RF0R & 3u) {
        uint32_t id = CAN_RI0R >> 3, low = CAN_RDL0R, high = CAN_RDH0R;
        uint8_t dlc = (uint8_t)(CAN_RDT0R & 0xFu), data[8];
        for (int k = 0; k < 4; k++) {
            data[k] = (uint8_t)(low >> (8 * k));
            data[4 + k] = (uint8_t)(high >> (8 * k));
        }
        CAN_RF0R = 1u << 5; /* release the FIFO output */
        if (asm_commission_is_command(id))
            commissioning(data, dlc > 8 ? 8 : dlc);
        else if (configured)
            asm_node_frame(&module.node, id, data, dlc > 8 ? 8 : dlc, now_ms());
    }
}

/* The servo: a pulse of 1,500 us at 0 degrees, 1,000 us more or less at +-90 (TIM3 counts microseconds); relaxed,
 * no pulse at all. */
static void joint_command(void *ctx, float degrees)
{
    (void)ctx;
    TIM_CCR1(TIM3) = (uint32_t)(PWM_CENTRE_US + degrees * (1000.0f / 90.0f) + 0.5f);
    TIM_CCER(TIM3) |= 1u;
}
static void joint_relax(void *ctx) { (void)ctx; TIM_CCER(TIM3) &= ~1u; }
/* The encoder counts from 0 at power-up, the joint's zero; no torque sensing on this board. */
static void joint_read(void *ctx, float *angle, float *torque, uint8_t *contact)
{
    (void)ctx;
    *angle = (float)(int32_t)TIM_CNT(TIM2) * (360.0f / ENCODER_COUNTS);
    *torque = 0.0f;
    *contact = (uint8_t)((GPIOA_IDR >> 2) & 1u);
}

static void joint_init(void)
{
    RCC_AHB1ENR |= 1u;                      /* GPIOA (pin modes and alternate functions: left to a real board) */
    RCC_APB1ENR |= 1u | 2u | (1u << 25);   /* TIM2, TIM3, CAN1 */
    TIM_SMCR(TIM2) = 3u;                    /* encoder mode 3 */
    TIM_CCMR1(TIM2) = 1u | (1u << 8);       /* TI1, TI2 */
    TIM_CNT(TIM2) = 0;
    TIM_CR1(TIM2) = 1u;
    TIM_PSC(TIM3) = 84u - 1u;               /* 84 MHz timer clock: 1 us */
    TIM_ARR(TIM3) = 20000u - 1u;            /* 50 Hz */
    TIM_CCMR1(TIM3) = (6u << 4) | (1u << 3); /* PWM mode 1, preload */
    TIM_CR1(TIM3) = 1u;
}

/* Where a debugger (or the emulator) finds what it reads and calls: the module, its e-stop, goal and angle, the gait
 * service's state, when the gait last started and gait.done, the millisecond count, and asm_node_local to make the
 * module's own requests. */
struct asm_probe {
    uint32_t version; /* 3: with the clock */
    struct asm_node *node;
    int (*local)(struct asm_node *node, const uint8_t *message, size_t length);
    void (*leave)(struct asm_node *node);
    uint32_t *now_ms;
    uint8_t *estop;
    float *goal, *angle;
    uint8_t *running;
    volatile uint32_t *milliseconds;
    uint32_t *ramp_start_ms;
    uint8_t *done;
    uint8_t *configured;
    struct asm_commission *commission;
    uint32_t (*clock)(void); /* now_ms: what the module's own requests are timed with */
};
__attribute__((section(".probe"), used)) const struct asm_probe asm_probe = {
    3u, &module.node, asm_node_local, asm_node_leave, &module.node.now_ms, &module.node.estop, &module.goal_v,
    &module.angle_v, &module.gait.service.running, &milliseconds, &module.gait.ramp_start_ms, &module.gait.done_v,
    &configured, &commission, now_ms};

/* Run the module under commission.node_id (none: answer only commissioning). The name is the flashed one under the
 * flashed ID, m<ID> under a commissioned one. */
static void boot_node(void)
{
    static const struct asm_port port = {can_send, 0, 0};
    static const struct asm_joint_port joint = {joint_command, joint_relax, joint_read, 0};
    uint8_t id = commission.node_id;
    configured = id != ASM_UNCONFIGURED;
    const char *name = (const char *)board_config.name;
    if (configured && id != board_config.node_id) {
        uint8_t k = 0;
        node_name[k++] = 'm';
        if (id >= 100)
            node_name[k++] = (char)('0' + id / 100);
        if (id >= 10)
            node_name[k++] = (char)('0' + id / 10 % 10);
        node_name[k++] = (char)('0' + id % 10);
        node_name[k] = 0;
        name = node_name;
    }
    if (configured) {
        struct asm_calibration calibration;
        asm_module_init(&module, name, id, &port, &joint, board_config.hardware_min, board_config.hardware_max,
                        now_ms());
        asm_module_set_type(&module, MODULE_TYPE);
        if (settings_calibration(&calibration))
            asm_module_calibrate(&module, &calibration); /* refused (no change) if the board's range has moved */
        asm_module_set_store(&module, store_calibration, 0);
        update_register(&module.node);
    }
    can_filters();
}

/* The stack's high-water mark: the stack is painted at boot and the lowest word ever overwritten found by a scan
 * that moves only down (a few words a tick at most). */
#define PAINT 0xC5C5C5C5u
extern uint32_t _stack_top, _ebss;
static uint32_t *lowest_used;

__attribute__((noinline)) static void stack_paint(void)
{
    uint32_t *sp;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    uint32_t *bottom = (uint32_t *)(((uintptr_t)&_ebss + 7u) & ~(uintptr_t)7u);
    for (uint32_t *at = bottom; at < sp - 16; at++) /* below this frame and a margin for the loop's own */
        *at = PAINT;
    lowest_used = sp - 16;
}

static uint32_t stack_used(void)
{
    uint32_t *bottom = (uint32_t *)(((uintptr_t)&_ebss + 7u) & ~(uintptr_t)7u);
    while (lowest_used > bottom && lowest_used[-1] != PAINT)
        lowest_used--;
    return (uint32_t)((uintptr_t)&_stack_top - (uintptr_t)lowest_used);
}

/* One control tick, timed by the cycle counter (SysTick's 1 ms = 168,000 cycles is far too coarse for a tick of a
 * few thousand); the worst and the stack's mark go into module.info. */
static void control_tick(void)
{
    static uint32_t worst;
    uint32_t start = DWT_CYCCNT;
    asm_module_tick(&module, milliseconds);
    uint32_t spent = DWT_CYCCNT - start;
    if (spent > worst)
        worst = spent;
    asm_module_measured(&module, worst, stack_used());
}

int main(void)
{
    stack_paint();
    DEMCR |= 1u << 24; /* the cycle counter */
    DWT_CYCCNT = 0;
    DWT_CTRL |= 1u;
    SYST_RVR = CONTROL_MS * CYCLES_PER_MS - 1u; /* a control period at 168 MHz (24 bits hold 99 ms) */
    SYST_CVR = 0;
    SYST_CSR = 7u;
    joint_init();
    uint8_t node_id = board_config.node_id; /* flashed with the image, or else ... */
    settings_node_id(&node_id);             /* ... as commissioned, which wins */
    asm_commission_init(&commission, (const uint8_t *)UID, node_id);
    update_boot();
    can_init();
    boot_node();
    uint32_t next_tick = milliseconds;
    for (;;) {
        can_receive();
        update_poll(milliseconds);
        if (!configured)
            continue;
        watch_neighbours();
        if ((int32_t)(milliseconds - next_tick) >= 0) {
            next_tick += CONTROL_MS;
            control_tick();
        }
    }
}

/* The vector table and reset: the stack top, then reset, and SysTick at index 15. */
extern uint32_t _sidata, _sdata, _edata, _sbss;
void Reset_Handler(void);
void Default_Handler(void) { for (;;) ; }
__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))(uintptr_t)&_stack_top, Reset_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, 0, 0, 0, 0, Default_Handler, Default_Handler, 0, Default_Handler,
    SysTick_Handler};

void Reset_Handler(void)
{
    SCB_CPACR |= 0xFu << 20; /* the FPU (CP10, CP11): the runtime computes in single precision */
    uint32_t *from = &_sidata, *to = &_sdata;
    while (to < &_edata)
        *to++ = *from++;
    for (to = &_sbss; to < &_ebss;)
        *to++ = 0;
    main();
}
