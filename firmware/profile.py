#!/usr/bin/env python3
"""Instruction profile of the benchmark image, by figure and by (inlined) function.

Runs the bench image under QEMU with `-icount shift=0 -d in_asm,exec,nochain`, streaming the
log through a FIFO (it is several GB), and charges every executed instruction to the figure
whose profiling mark (`mark_*` in src/bin/bench.rs) started the timed region it ran in, and to
the innermost function that the debug information says the instruction belongs to (so inlined
functions count separately from their callers).

    python3 profile.py [path/to/bench] > profile.txt

Needs qemu-system-arm and llvm-symbolizer (or llvm-addr2line) on PATH. Prints, per figure,
the instructions per occurrence of each function above 0.5% of the figure.
"""

import collections
import os
import re
import subprocess
import sys
import tempfile

BENCH = sys.argv[1] if len(sys.argv) > 1 else "target/thumbv7em-none-eabihf/release/bench"
MARKS = ["mark_imu_steps", "mark_correspondence", "mark_contour", "mark_message",
         "mark_frame_part", "mark_other", "mark_stop"]
MODELS = ["gyro", "gravity", "acc", "vision"]


def symbols(path):
    """Address of each mark function."""
    out = subprocess.run(["llvm-nm", "-C", path], capture_output=True, text=True,
                         check=True).stdout
    found = {}
    for line in out.splitlines():
        parts = line.split(None, 2)
        if len(parts) == 3:
            for m in MARKS:
                if re.search(r"(^|::)" + m + r"(::h[0-9a-f]+)?$", parts[2]):
                    found[int(parts[0], 16) & ~1] = m
    missing = set(MARKS) - set(found.values())
    if missing:
        sys.exit(f"marks not found in {path}: {sorted(missing)}")
    return found


def builtin_ranges(path):
    """Address ranges of memcpy/memset and their helpers (their callers are profiled too)."""
    out = subprocess.run(["llvm-nm", "-S", "-C", path], capture_output=True, text=True,
                         check=True).stdout
    ranges = []
    for line in out.splitlines():
        parts = line.split(None, 3)
        if len(parts) == 4 and re.search(r"compiler_builtins::mem|__aeabi_mem", parts[3]):
            a = int(parts[0], 16) & ~1
            ranges.append((a, a + int(parts[1], 16)))
    return ranges


def run(path, marks):
    """(phase -> {(pc, cflags): executions}), (pc, cflags) -> instruction addresses."""
    tmp = tempfile.mkdtemp()
    fifo = os.path.join(tmp, "log")
    os.mkfifo(fifo)
    qemu = subprocess.Popen(
        ["qemu-system-arm", "-machine", "mps2-an386", "-cpu", "cortex-m4", "-nographic",
         "-monitor", "none", "-icount", "shift=0", "-semihosting-config",
         "enable=on,target=native", "-kernel", path, "-d", "in_asm,exec,nochain", "-D", fifo],
        stdout=subprocess.DEVNULL)
    blocks = {}
    counts = collections.defaultdict(collections.Counter)
    occurrences = collections.Counter()
    pending = []  # instruction addresses of the last translated block
    ranges = builtin_ranges(path)
    callers = collections.defaultdict(collections.Counter)
    prev_pc, caller, in_builtin = 0, 0, False
    phase = None
    session = 0
    seen_counted = False
    with open(fifo) as log:
        for line in log:
            if line.startswith("Trace"):
                # Trace 0: host [cs_base/pc/flags/cflags] symbol
                fields = line[line.index("[") + 1:line.index("]")].split("/")
                pc = int(fields[1], 16)
                key = (pc, fields[3])
                if pending:
                    blocks[key] = pending
                    pending = []
                mark = marks.get(pc)
                if mark == "mark_stop":
                    phase = None
                elif mark == "mark_other":
                    if seen_counted:
                        session += 1
                        seen_counted = False
                    phase = None
                elif mark is not None:
                    if mark in ("mark_message", "mark_frame_part"):
                        seen_counted = True
                        name = mark[5:] + ("_acc", "_vision")[min(session, 1)]
                        phase = name
                    else:
                        k = occurrences[mark]
                        occurrences[mark] += 1
                        if mark == "mark_imu_steps":
                            phase = "imu_steps_" + MODELS[k]
                        else:
                            phase = mark[5:] + ("_acc", "_vision")[k // 16]
                    occurrences[phase] += 1
                elif phase is not None:
                    counts[phase][key] += 1
                    builtin = any(a <= pc < b for a, b in ranges)
                    if builtin and not in_builtin:
                        caller = prev_pc
                    if builtin:
                        callers[phase][(caller, key)] += 1
                    in_builtin = builtin
                prev_pc = pc
            elif line.startswith("0x"):
                pending.append(int(line[2:10], 16))
    qemu.wait()
    os.unlink(fifo)
    os.rmdir(tmp)
    return counts, blocks, occurrences, callers


# Frames that are plumbing, not the project's code: an instruction is charged to the innermost
# frame that is none of these (core's iterators and operators, nalgebra's and simba's
# element-wise helpers are inlined everywhere).
PLUMBING = re.compile(r"^(<)?(core|alloc|nalgebra|simba|num_traits)::|^<(f32|u8|u32|usize|\*mut u32|"
                      r"\*const u32|\[T\]) as core::|^<\*(mut|const) |^<(f32|u8|u32|usize)>::")


def demangle(fn):
    """Rust legacy symbol escapes that llvm-symbolizer 14 leaves in place."""
    for a, b in [("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("$C$", ","), ("$BP$", "*"),
                 ("$RF$", "&"), ("$u7b$", "{"), ("$u7d$", "}"), ("$u5b$", "["), ("$u5d$", "]"),
                 ("$u27$", "'"), ("..", "::")]:
        fn = fn.replace(a, b)
    return re.sub(r"(^|::)_<", r"\1<", fn)


def symbolize(path, addrs):
    """Innermost function of each address that is the project's own (not core's plumbing)."""
    addrs = sorted(addrs)
    tool = "llvm-symbolizer"
    proc = subprocess.run([tool, "--inlining", "--functions=linkage", "--demangle",
                           "--obj=" + path], input="\n".join(hex(a) for a in addrs) + "\n",
                          capture_output=True, text=True, check=True)
    # One group per address, separated by empty lines: function, file:line pairs, innermost
    # frame first.
    groups = [g.splitlines() for g in proc.stdout.strip("\n").split("\n\n")]
    names = {}
    for a, g in zip(addrs, groups):
        frames = [short(demangle(f)) for f in g[0::2]] or ["?"]
        own = next((f for f in frames if not PLUMBING.search(f)), frames[-1])
        names[a] = (own, frames[0])
    return names


def caller_names(path, addrs):
    """Inline chain (outermost last) of each block address, as function names."""
    proc = subprocess.run(["llvm-symbolizer", "--inlining", "--functions=linkage", "--obj=" + path],
                          input="\n".join(hex(a) for a in addrs) + "\n", capture_output=True,
                          text=True, check=True)
    groups = [g.splitlines() for g in proc.stdout.strip("\n").split("\n\n")]
    return {a: " < ".join(short(demangle(f)).split("::")[-1] + "@" + w.split("/")[-1]
                          for f, w in zip(g[0::2], g[1::2]) if not PLUMBING.search(short(demangle(f))))
            for a, g in zip(addrs, groups)}


def short(fn):
    """A demangled Rust name without its hash and crate-internal noise."""
    fn = re.sub(r"::h[0-9a-f]{16}$", "", fn)
    return fn.replace("fusion_core::", "")


def main():
    marks = symbols(BENCH)
    counts, blocks, occurrences, callers = run(BENCH, marks)
    addrs = set()
    for per in counts.values():
        for key in per:
            addrs.update(blocks.get(key, ()))
    names = symbolize(BENCH, addrs)
    if os.environ.get("PROFILE_DUMP"):
        # Executions of each instruction address, by figure (for a look at the hot loops).
        import json
        per_addr = {ph: collections.Counter() for ph in counts}
        for ph, per in counts.items():
            for key, n in per.items():
                for a in blocks.get(key, ()):
                    per_addr[ph][a] += n
        with open(os.environ["PROFILE_DUMP"], "w") as f:
            json.dump({ph: {hex(a): n for a, n in c.items()} for ph, c in per_addr.items()}, f)
    for phase in sorted(counts):
        per_fn = collections.Counter()
        for key, n in counts[phase].items():
            for a in blocks.get(key, ()):
                per_fn[names[a][0]] += n
        occ = max(occurrences[phase], 1)
        # The figures: per IMU step (64 per timed loop), per frame (three parts of 16, 16, 8).
        unit = "occurrence"
        if phase.startswith("imu_steps"):
            occ, unit = occ * 64, "step"
        elif phase.startswith("frame_part"):
            occ, unit = occ / 3, "frame"
        total = sum(per_fn.values())
        print(f"\n== {phase}: {occ:.0f} x, {total / occ:.0f} instructions per {unit}")
        for fn, n in per_fn.most_common():
            if n < 0.005 * total:
                break
            print(f"{n / occ:10.0f}  {100 * n / total:5.1f}%  {fn}")
        # memcpy/memset by calling block (the block that branched into them).
        by_caller = collections.Counter()
        for (c, key), k in callers[phase].items():
            by_caller[c] += k * len(blocks.get(key, ()))
        top = [(c, k) for c, k in by_caller.most_common(8) if k >= 0.005 * total]
        if top:
            where = caller_names(BENCH, [c for c, _ in top])
            for c, k in top:
                print(f"{k / occ:10.0f}  memcpy/memset called from {hex(c)} {where[c]}")


if __name__ == "__main__":
    main()
