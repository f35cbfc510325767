"""The per-block hook of emu.Sim and the flash interface's common paths in C (compiled once with the system's C
compiler, cached by source hash).

A run's host time is mostly unicorn's per-block callback into Python (≈ 3-5 µs a block, ≈ 2 400 blocks per FPGA
frame). The C hook counts instructions (exactly: a table of instruction starts per flash halfword, from
llvm-objdump, the same count as boot.Image.insns_in), keeps the spin window's block set, and calls back into Python
only when something needs it: a marked block (defmt, task polls, handlers), a due timed check, the end of a spin
window. Without a C compiler, emu.Sim falls back to the same logic in Python (slower, same results).

The flash interface (`fw_flash_read`/`fw_flash_write`, mapped over its 1 KiB, and `fw_flash_store`, the store hook
over the flash): boot.FlashIf is the model and keeps its registers in this struct; the C code does what an
unlock-program-wait-lock sequence does most (SR/CR/ACR reads, SR clears, a valid key sequence, CR writes without
STRT while unlocked, a program of an erased location with PG set at the right size) and hands everything else to
FlashIf through `fcb` (kind 0 read, 1 write, 2 store: the value the flash holds after the store, which C restores
right after it, at the next block or flash access, when it is not the value stored). About 1 µs per word program
instead of ≈ 35 µs through Python.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile

SOURCE = r"""
#include <stdint.h>
#include <string.h>
typedef void (*py_cb)(uint32_t addr, uint32_t size, int32_t reason);
typedef uint64_t (*flash_cb)(int32_t kind, uint32_t off, uint32_t size, uint64_t value);
typedef struct {
    uint64_t insns, next_check, win_start, spin_window;
    const uint32_t *idx;  /* instructions starting before base + 2*h, h = 0 .. len_hw */
    const uint8_t *hot;   /* per halfword: Python wants to see a block starting here */
    uint32_t base, len_hw, last_addr, last_size;
    uint32_t win[8];
    int32_t nwin, win_over;
    py_cb cb;
    /* virtual time: t_base + (insns - insn_base) / hz (insn_base stays in Python) */
    double t_base, hz;
    uint64_t mmio_count;
    /* the flash interface (boot.FlashIf's registers) and the flash memory */
    uint8_t *mem;
    uint32_t f_acr, f_cr, f_sr, f_optcr, f_key, f_dead, f_busy, f_bsy_polls, f_fast;
    uint32_t fix_pending, fix_off, fix_size;
    uint64_t fix_val;
    double f_prog_s, f_program_s;
    uint64_t f_programs, f_bytes, f_unlocks;
    flash_cb fcb;
} state_t;

static void apply_fix(state_t *s) {
    if (s->fix_pending) {
        memcpy(s->mem + s->fix_off, &s->fix_val, s->fix_size);
        s->fix_pending = 0;
    }
}

void fw_block(void *uc, uint64_t address, uint32_t size, void *user) {
    state_t *s = (state_t *)user;
    uint32_t a = (uint32_t)address, n = 1;
    int32_t reason = 0;
    uint32_t off = a - s->base;
    if (s->fix_pending) apply_fix(s);
    if (a >= s->base && (off >> 1) + ((size + 1) >> 1) <= s->len_hw) {
        uint32_t i = off >> 1, j = (off + size) >> 1;
        n = s->idx[j] - s->idx[i];
        if (n == 0) n = 1;
        if (s->hot[i]) reason |= 1;
    } else {
        reason |= 8; /* outside the table: Python counts it */
    }
    s->insns += n;
    s->last_addr = a;
    s->last_size = size;
    if (!s->win_over) {
        int32_t k;
        for (k = 0; k < s->nwin; k++)
            if (s->win[k] == a) break;
        if (k == s->nwin) {
            if (s->nwin < 8) s->win[s->nwin++] = a;
            else s->win_over = 1;
        }
    }
    if (s->insns >= s->next_check) reason |= 2;
    if (s->insns - s->win_start >= s->spin_window) reason |= 4;
    if (reason) s->cb(a, size, reason);
}

/* The flash interface's common accesses (boot.FlashIf is the model; anything else is handed to it). */
#define F_PG 1u
#define F_STRT (1u << 16)
#define F_EOPIE (1u << 24)
#define F_ERRIE (1u << 25)
#define F_LOCK (1u << 31)
#define F_EOP 1u
#define F_BSY (1u << 16)
#define F_W1C 0xF3u

uint64_t fw_flash_read(void *uc, uint64_t off, unsigned size, void *user) {
    state_t *s = (state_t *)user;
    uint32_t v;
    s->mmio_count++;
    apply_fix(s);
    if (!s->f_fast) return s->fcb(0, (uint32_t)off, size, 0);
    switch (off & ~3u) {
    case 0x00: v = s->f_acr; break;
    case 0x04: case 0x08: v = 0; break;
    case 0x0C:
        v = s->f_sr;
        if (s->f_busy) { s->f_busy--; v |= F_BSY; }
        break;
    case 0x10: v = s->f_cr; break;
    case 0x14: v = s->f_optcr; break;
    default: return s->fcb(0, (uint32_t)off, size, 0);
    }
    v >>= 8 * (off & 3);
    return size >= 4 ? v : v & ((1u << (8 * size)) - 1);
}

void fw_flash_write(void *uc, uint64_t off, unsigned size, uint64_t value, void *user) {
    state_t *s = (state_t *)user;
    uint32_t v = (uint32_t)value;
    s->mmio_count++;
    apply_fix(s);
    if (s->f_fast && size == 4) {
        if (off == 0x0C) { s->f_sr &= ~(v & F_W1C); return; }
        if (off == 0x04 && (s->f_cr & F_LOCK) && !s->f_dead) {
            if (s->f_key == 0 && v == 0x45670123u) { s->f_key = 1; return; }
            if (s->f_key == 1 && v == 0xCDEF89ABu) { s->f_cr &= ~F_LOCK; s->f_key = 0; s->f_unlocks++; return; }
        }
        if (off == 0x10 && !(s->f_cr & F_LOCK) && !(v & F_STRT)) {
            s->f_busy = 0;
            s->f_cr = v;
            if (v & (F_EOPIE | F_ERRIE)) s->next_check = 0; /* the flash interrupt may pend */
            return;
        }
    }
    s->fcb(1, (uint32_t)off, size, value);
}

static int wrp(const state_t *s, uint32_t off) {
    uint32_t snb = off < 0x10000 ? off >> 14 : off < 0x20000 ? 4 : 4 + (off >> 17);
    return !((s->f_optcr >> 16) & (1u << snb));
}

/* UC_HOOK_MEM_WRITE over [0, 0x0810_0000): called before the store, which then writes the raw value. */
void fw_flash_store(void *uc, int type, uint64_t address, int size, int64_t value, void *user) {
    state_t *s = (state_t *)user;
    uint32_t off;
    uint64_t mask, val, old = 0, fin;
    if (address < 0x100000) off = (uint32_t)address;
    else if (address >= 0x08000000u && address < 0x08100000u) off = (uint32_t)(address - 0x08000000u);
    else return;
    apply_fix(s);
    s->mmio_count++;
    mask = size >= 8 ? ~0ull : (1ull << (8 * size)) - 1;
    val = (uint64_t)value & mask;
    if (s->f_fast && !(s->f_cr & F_LOCK) && (s->f_cr & F_PG) && size == (1 << ((s->f_cr >> 8) & 3))
        && (off & 15) + (uint32_t)size <= 16 && !wrp(s, off)) {
        memcpy(&old, s->mem + off, size);
        if (old == mask) { /* an erased location: the store programs exactly the value */
            uint64_t c = (uint64_t)(s->f_prog_s * s->hz);
            s->f_programs++;
            s->f_bytes += size;
            s->t_base += s->f_prog_s; /* the CPU stalls: virtual time moves on */
            s->f_program_s += s->f_prog_s;
            s->next_check = s->next_check > c ? s->next_check - c : 0;
            if (s->f_cr & F_EOPIE) s->f_sr |= F_EOP;
            s->f_busy = s->f_bsy_polls;
            return;
        }
    }
    fin = s->fcb(2, off, size, val);
    if (fin != val) {
        s->fix_pending = 1;
        s->fix_off = off;
        s->fix_size = size;
        s->fix_val = fin;
    }
}
"""

PY_CB = ctypes.CFUNCTYPE(None, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_int32)
FLASH_CB = ctypes.CFUNCTYPE(ctypes.c_uint64, ctypes.c_int32, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint64)
u32, u64, f64 = ctypes.c_uint32, ctypes.c_uint64, ctypes.c_double


class State(ctypes.Structure):
    _fields_ = [("insns", u64), ("next_check", u64), ("win_start", u64), ("spin_window", u64),
                ("idx", ctypes.POINTER(u32)), ("hot", ctypes.POINTER(ctypes.c_uint8)), ("base", u32),
                ("len_hw", u32), ("last_addr", u32), ("last_size", u32), ("win", u32 * 8),
                ("nwin", ctypes.c_int32), ("win_over", ctypes.c_int32), ("cb", PY_CB),
                ("t_base", f64), ("hz", f64), ("mmio_count", u64),
                ("mem", ctypes.POINTER(ctypes.c_uint8)),
                ("f_acr", u32), ("f_cr", u32), ("f_sr", u32), ("f_optcr", u32), ("f_key", u32), ("f_dead", u32),
                ("f_busy", u32), ("f_bsy_polls", u32), ("f_fast", u32),
                ("fix_pending", u32), ("fix_off", u32), ("fix_size", u32), ("fix_val", u64),
                ("f_prog_s", f64), ("f_program_s", f64), ("f_programs", u64), ("f_bytes", u64), ("f_unlocks", u64),
                ("fcb", FLASH_CB)]


_lib = None
_lib_error = None


def library():
    """The compiled hook (ctypes.CDLL) or None (no compiler: the caller falls back to Python)."""
    global _lib, _lib_error
    if _lib is not None or _lib_error is not None:
        return _lib
    if os.environ.get("FW_CHECK_NO_C"):
        _lib_error = "disabled by FW_CHECK_NO_C"
        return None
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc") or shutil.which("clang")
    if not cc:
        _lib_error = "no C compiler"
        return None
    h = hashlib.sha256(SOURCE.encode()).hexdigest()[:16]
    so = os.path.join(tempfile.gettempdir(), f"fw-check-fastblock-{h}-{os.getuid()}.so")
    if not os.path.isfile(so):
        d = tempfile.mkdtemp(prefix="fastblock-")
        try:
            src = os.path.join(d, "fastblock.c")
            with open(src, "w") as f:
                f.write(SOURCE)
            tmp = os.path.join(d, "fastblock.so")
            r = subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", tmp, src], capture_output=True, text=True)
            if r.returncode != 0:
                _lib_error = f"{cc} failed: {r.stderr.strip()[:300]}"
                return None
            os.replace(tmp, so)
        finally:
            shutil.rmtree(d, True)
    try:
        _lib = ctypes.CDLL(so)
    except OSError as e:
        _lib_error = str(e)
        return None
    return _lib


def tables(img, base: int, size: int):
    """(idx, hot) arrays over the flash image's halfwords."""
    len_hw = size // 2
    idx = (ctypes.c_uint32 * (len_hw + 1))()
    count = 0
    starts = set(a - base for a in img.insn_sorted if base <= a < base + size)
    for h in range(len_hw + 1):
        idx[h] = count
        if 2 * h in starts:
            count += 1
    hot = (ctypes.c_uint8 * (len_hw + 1))()
    return idx, hot, len_hw
