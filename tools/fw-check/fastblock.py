"""The per-block hook of emu.Sim in C (compiled once with the system's C compiler, cached by source hash).

A run's host time is mostly unicorn's per-block callback into Python (≈ 3-5 µs a block, ≈ 2 400 blocks per FPGA
frame). The C hook counts instructions (exactly: a table of instruction starts per flash halfword, from
llvm-objdump, the same count as boot.Image.insns_in), keeps the spin window's block set, and calls back into Python
only when something needs it: a marked block (defmt, task polls, handlers), a due timed check, the end of a spin
window. Without a C compiler, emu.Sim falls back to the same logic in Python (slower, same results).
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
typedef void (*py_cb)(uint32_t addr, uint32_t size, int32_t reason);
typedef struct {
    uint64_t insns, next_check, win_start, spin_window;
    const uint32_t *idx;  /* instructions starting before base + 2*h, h = 0 .. len_hw */
    const uint8_t *hot;   /* per halfword: Python wants to see a block starting here */
    uint32_t base, len_hw, last_addr, last_size;
    uint32_t win[8];
    int32_t nwin, win_over;
    py_cb cb;
} state_t;

void fw_block(void *uc, uint64_t address, uint32_t size, void *user) {
    state_t *s = (state_t *)user;
    uint32_t a = (uint32_t)address, n = 1;
    int32_t reason = 0;
    uint32_t off = a - s->base;
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
"""

PY_CB = ctypes.CFUNCTYPE(None, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_int32)


class State(ctypes.Structure):
    _fields_ = [("insns", ctypes.c_uint64), ("next_check", ctypes.c_uint64), ("win_start", ctypes.c_uint64),
                ("spin_window", ctypes.c_uint64), ("idx", ctypes.POINTER(ctypes.c_uint32)),
                ("hot", ctypes.POINTER(ctypes.c_uint8)), ("base", ctypes.c_uint32), ("len_hw", ctypes.c_uint32),
                ("last_addr", ctypes.c_uint32), ("last_size", ctypes.c_uint32), ("win", ctypes.c_uint32 * 8),
                ("nwin", ctypes.c_int32), ("win_over", ctypes.c_int32), ("cb", PY_CB)]


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
