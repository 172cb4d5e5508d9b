/* The emulated core's clock (asm_module/emulator.py), in C: Unicorn calls asm_cortex_block for every translated
 * block the image executes, and what it does there — count the block's instructions into the cycle count, let
 * SysTick reach zero, let the independent watchdog run out, stop the core where a pending SysTick is taken — ran
 * as a Python callback before: two to three microseconds a block, and the GIL taken back for each (eight boards
 * in one process waited on one another's blocks). The rules are the same as the Python ones were; the state is a
 * struct the emulator reads and writes through ctypes (asm_module/cortex_clock.py), and the Unicorn functions it
 * calls are given to it as pointers, so this library needs no Unicorn headers and links against nothing. */
#include <stdint.h>

typedef int (*reg_read_fn)(void *uc, int regid, void *value);
typedef int (*emu_stop_fn)(void *uc);
typedef int (*mem_read_fn)(void *uc, uint64_t address, void *bytes, uint64_t size);

#define CACHE_SLOTS 4096u
#define MAX_BLOCK 4096u

enum { REASON_NONE, REASON_SYSTICK, REASON_WATCHDOG, REASON_BUDGET };

struct block_entry {
    uint64_t address;
    uint32_t size, count;
};

struct core_clock {
    uint64_t cycles;       /* instructions executed since reset: the emulated clock at one per cycle */
    uint64_t systick_next; /* the cycle at which SysTick next reaches zero (while enabled) */
    uint64_t watchdog_at;  /* the cycle at which the independent watchdog resets the board; ~0 until started */
    uint64_t run_until;    /* the cycle at which a run gives the host its turn back, whatever the image does: a run
                            * keeps the host's interpreter lock, so an image spinning with no interrupt due must
                            * not keep it for good (~0: no bound) */
    uint32_t csr, rvr;     /* SysTick's ENABLE, TICKINT, CLKSOURCE and reload */
    uint32_t countflag;    /* SysTick reached zero since CSR was last read */
    uint32_t pending;      /* a SysTick interrupt waits to be taken */
    uint32_t depth;        /* exceptions being handled: none is taken inside one */
    uint32_t calling;      /* the host is calling into the image: no interrupt is taken */
    uint32_t reason;       /* why the core was stopped (REASON_*, or the emulator's own codes): 0 while running */
    int32_t xpsr;          /* Unicorn's register ID of xPSR */
    reg_read_fn reg_read;
    emu_stop_fn emu_stop;
    mem_read_fn mem_read;
    struct block_entry cache[CACHE_SLOTS];
};

/* Instructions in the block of ``size`` bytes at ``address``: Thumb-2, a halfword whose top five bits are 0b11101,
 * 0b11110 or 0b11111 starts a 32-bit instruction. Counted once per block (address and size) and kept. */
static uint32_t instructions(struct core_clock *c, void *uc, uint64_t address, uint32_t size)
{
    struct block_entry *e = &c->cache[(address >> 1) & (CACHE_SLOTS - 1u)];
    if (e->address == address && e->size == size)
        return e->count;
    uint8_t code[MAX_BLOCK + 2];
    uint32_t count = 0, at = 0, n = size < MAX_BLOCK ? size : MAX_BLOCK;
    if (c->mem_read(uc, address, code, n))
        return size / 2u; /* unreadable (never for code that just ran): one instruction a halfword */
    while (at < n) {
        uint8_t top = code[at + 1] >> 3;
        at += top == 0x1D || top == 0x1E || top == 0x1F ? 4u : 2u;
        count++;
    }
    if (size > n)
        count += (size - n) / 2u; /* a block longer than any Unicorn translates */
    *e = (struct block_entry){address, size, count};
    return count;
}

/* SysTick reached zero (once or more) by now: COUNTFLAG, and the interrupt pending if TICKINT. */
void asm_cortex_count_down(struct core_clock *c)
{
    if (c->cycles >= c->systick_next && (c->csr & 1u) && c->rvr) {
        uint64_t period = (uint64_t)c->rvr + 1u;
        c->systick_next += ((c->cycles - c->systick_next) / period + 1u) * period;
        c->countflag = 1;
        if (c->csr & 2u)
            c->pending = 1;
    }
}

/* Unicorn's UC_HOOK_BLOCK callback, ``user_data`` the core's clock. A block the core is stopped before (a reset,
 * an interrupt taken first) does not run now, and its instructions are counted when it does. */
void asm_cortex_block(void *uc, uint64_t address, uint32_t size, void *user_data)
{
    struct core_clock *c = user_data;
    uint32_t count = instructions(c, uc, address, size);
    c->cycles += count;
    if (c->cycles >= c->systick_next)
        asm_cortex_count_down(c);
    if (c->cycles >= c->watchdog_at && !c->reason) {
        c->reason = REASON_WATCHDOG;
        c->cycles -= count;
        c->emu_stop(uc);
    }
    if (c->cycles >= c->run_until && !c->reason) {
        c->reason = REASON_BUDGET;
        c->cycles -= count;
        c->emu_stop(uc);
    }
    if (c->pending && !c->depth && !c->calling && !c->reason) {
        uint32_t xpsr = 0;
        c->reg_read(uc, c->xpsr, &xpsr);
        if (!(xpsr & 0x0600FC00u)) { /* never inside an IT block */
            c->pending = 0;
            c->reason = REASON_SYSTICK;
            c->cycles -= count;
            c->emu_stop(uc);
        }
    }
}
