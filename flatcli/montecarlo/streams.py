"""The first uniform variates of many trials' streams at once, as numpy draws them.

A trial's stream is ``default_rng(SeedSequence(seed, spawn_key=(trial, slot)))``
(``flatcli.experiment.trial_stream``): numpy's PCG64 seeded by the SeedSequence's hash of
the seed and the key. Built one trial at a time that costs about 15-35 us a trial, as much
as the rest of a chunk's bookkeeping; ``uniform_variates`` computes the same numbers for a
whole chunk in one compiled loop: the SeedSequence's entropy mixing and state (O'Neill's
seed_seq hash, as numpy's ``bit_generator.SeedSequence``), PCG64's seeding and its XSL-RR
output (``pcg64_set_seed``, ``pcg64_next64``), and ``Generator.random``'s doubles
((next64 >> 11) 2^-53). tests/test_montecarlo_draws.py compares them with numpy's bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import kernel

_MASK32 = 0xFFFFFFFF
# SeedSequence's hash constants (numpy/random/bit_generator.pyx)
_INIT_A = np.uint32(0x43B0D7E5)
_MULT_A = np.uint32(0x931E8875)
_INIT_B = np.uint32(0x8B51F9DD)
_MULT_B = np.uint32(0x58F38DED)
_MIX_MULT_L = np.uint32(0xCA01F9DD)
_MIX_MULT_R = np.uint32(0x4973F715)
_XSHIFT = np.uint32(16)
_POOL = 4
# PCG64's 128-bit multiplier, high and low words (pcg64.h: PCG_DEFAULT_MULTIPLIER_128)
_MULT_HI = np.uint64(2549297995355413924)
_MULT_LO = np.uint64(4865540595714422341)


def words(value: int) -> list[int]:
    """A non-negative int as SeedSequence takes it: 32-bit words, least significant first
    (0 is one word)."""
    if value < 0:
        raise ValueError("a stream's seed and key are >= 0")
    out = [value & _MASK32]
    value >>= 32
    while value:
        out.append(value & _MASK32)
        value >>= 32
    return out


@kernel
def _hashmix(value: np.uint32, hash_const: NDArray[np.uint32]) -> np.uint32:
    value = np.uint32(value ^ hash_const[0])
    hash_const[0] = np.uint32(hash_const[0] * _MULT_A)
    value = np.uint32(value * hash_const[0])
    return np.uint32(value ^ (value >> _XSHIFT))


@kernel
def _mulhi(a: np.uint64, b: np.uint64) -> np.uint64:
    """The high 64 bits of the 128-bit product of two 64-bit words."""
    mask = np.uint64(0xFFFFFFFF)
    shift = np.uint64(32)
    a_lo, a_hi = a & mask, a >> shift
    b_lo, b_hi = b & mask, b >> shift
    lo_lo = a_lo * b_lo
    hi_lo = a_hi * b_lo
    lo_hi = a_lo * b_hi
    hi_hi = a_hi * b_hi
    cross = (lo_lo >> shift) + (hi_lo & mask) + lo_hi
    return np.uint64(hi_hi + (hi_lo >> shift) + (cross >> shift))


@kernel
def _step(state: NDArray[np.uint64], inc_hi: np.uint64, inc_lo: np.uint64) -> None:
    """state = state * MULT + inc (mod 2^128); state = (high, low)."""
    hi, lo = state[0], state[1]
    new_lo = np.uint64(lo * _MULT_LO)
    new_hi = np.uint64(_mulhi(lo, _MULT_LO) + hi * _MULT_LO + lo * _MULT_HI)
    low = np.uint64(new_lo + inc_lo)
    carry = np.uint64(1) if low < new_lo else np.uint64(0)
    state[0] = np.uint64(new_hi + inc_hi + carry)
    state[1] = low


@kernel
def _variates(entropy: NDArray[np.uint32], offsets: NDArray[np.int64], count: int,
              scratch: NDArray[np.uint32], state: NDArray[np.uint64],
              out: NDArray[np.float64]) -> None:
    """Row r of ``out``: the first ``count`` doubles of the PCG64 seeded by the SeedSequence
    whose assembled entropy is entropy[offsets[r]:offsets[r + 1]]."""
    mixer = scratch[:_POOL]
    hash_const = scratch[_POOL:_POOL + 1]
    words32 = scratch[_POOL + 1:_POOL + 9]
    for r in range(out.shape[0]):
        row = entropy[offsets[r]:offsets[r + 1]]
        hash_const[0] = _INIT_A
        for i in range(_POOL):  # mix_entropy
            mixer[i] = _hashmix(row[i] if i < row.shape[0] else np.uint32(0), hash_const)
        for i_src in range(_POOL):
            for i_dst in range(_POOL):
                if i_src != i_dst:
                    x = mixer[i_dst]
                    y = _hashmix(mixer[i_src], hash_const)
                    result = np.uint32(np.uint32(_MIX_MULT_L * x) - np.uint32(_MIX_MULT_R * y))
                    mixer[i_dst] = np.uint32(result ^ (result >> _XSHIFT))
        for i_src in range(_POOL, row.shape[0]):
            for i_dst in range(_POOL):
                x = mixer[i_dst]
                y = _hashmix(row[i_src], hash_const)
                result = np.uint32(np.uint32(_MIX_MULT_L * x) - np.uint32(_MIX_MULT_R * y))
                mixer[i_dst] = np.uint32(result ^ (result >> _XSHIFT))
        hash_b = _INIT_B
        for i_dst in range(8):  # generate_state(4, uint64): 8 words from the cycled pool
            value = np.uint32(mixer[i_dst % _POOL] ^ hash_b)
            hash_b = np.uint32(hash_b * _MULT_B)
            value = np.uint32(value * hash_b)
            words32[i_dst] = np.uint32(value ^ (value >> _XSHIFT))
        seed_hi = np.uint64(words32[0]) | (np.uint64(words32[1]) << np.uint64(32))
        seed_lo = np.uint64(words32[2]) | (np.uint64(words32[3]) << np.uint64(32))
        inc_in_hi = np.uint64(words32[4]) | (np.uint64(words32[5]) << np.uint64(32))
        inc_in_lo = np.uint64(words32[6]) | (np.uint64(words32[7]) << np.uint64(32))
        # pcg64_srandom_r: inc = (initseq << 1) | 1; state = 0; step; state += seed; step
        inc_hi = np.uint64((inc_in_hi << np.uint64(1)) | (inc_in_lo >> np.uint64(63)))
        inc_lo = np.uint64((inc_in_lo << np.uint64(1)) | np.uint64(1))
        state[0] = np.uint64(0)
        state[1] = np.uint64(0)
        _step(state, inc_hi, inc_lo)
        low = np.uint64(state[1] + seed_lo)
        carry = np.uint64(1) if low < state[1] else np.uint64(0)
        state[0] = np.uint64(state[0] + seed_hi + carry)
        state[1] = low
        _step(state, inc_hi, inc_lo)
        for k in range(count):  # Generator.random: next64 >> 11 times 2^-53
            _step(state, inc_hi, inc_lo)
            xored = np.uint64(state[0] ^ state[1])
            rot = np.uint64(state[0] >> np.uint64(58))
            output = np.uint64((xored >> rot) | (xored << ((np.uint64(64) - rot)
                                                            & np.uint64(63))))
            out[r, k] = float(output >> np.uint64(11)) * (1.0 / 9007199254740992.0)


def uniform_variates(seed: int, trials: Sequence[int], slot: int, count: int
                     ) -> NDArray[np.float64]:
    """(len(trials), count): row i is ``trial_stream(seed, trials[i], slot).random(count)``,
    to the bit."""
    run = words(seed)
    if len(run) < _POOL:  # numpy pads the run entropy to the pool when there is a key
        run = run + [0] * (_POOL - len(run))
    rows = [run + words(int(t)) + words(slot) for t in trials]
    offsets = np.zeros(len(rows) + 1, dtype=np.int64)
    np.cumsum([len(r) for r in rows], out=offsets[1:])
    entropy = np.array([w for r in rows for w in r], dtype=np.uint32)
    out = np.empty((len(rows), count))
    if rows:
        _variates(entropy, offsets, count, np.zeros(_POOL + 9, dtype=np.uint32),
                  np.zeros(2, dtype=np.uint64), out)
    return out
