"""Cost of the generated C controller on the Crazyflie's STM32F405 (Cortex-M4F, 168 MHz), estimated.

    python benchmarks/onboard_cost.py [checkpoint=...]

Method (all with the firmware's flags, ``arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb
-mfloat-abi=hard -mfpu=fpv4-sp-d16 -fno-math-errno -ffp-contract=off``, at ``-Os`` as the
firmware builds and at ``-O2``):

* flash and static RAM: ``arm-none-eabi-size`` of ``datt_policy.o`` (text = code + the weights);
* stack: ``-fstack-usage`` of every function on the deepest call path of ``datt_act`` and of
  ``datt_l1_step``;
* instructions per step: executed, counted under ``qemu-system-arm -M netduinoplus2 -icount
  shift=0`` by SysTick around one call, calibrated with a loop of 200000 known instructions;
* cycles per step: that count times a cycles-per-instruction figure from the disassembly of the
  hottest loop (``linear``'s inner loop): VLDR 2 cycles (1 when it follows another load, the
  optimistic bound), VMLA 3, VMUL/VADD and integer ops 1, a taken branch 2 extra (Cortex-M4
  TRM); and,
  as a cross-check, the MAC count times the cycles per MAC implied by the published onboard MLP
  figures (learning-to-fly / RLtools on the same MCU: 743 µs generic C, 478 µs CMSIS-DSP,
  293 µs hand-optimised for a 146-64-64-4 MLP = 13,696 MACs -> 9.1 / 5.9 / 3.6 cycles per MAC;
  the network size is our reading of their paper, not measured).

qemu is not cycle-accurate (no wait states, no pipeline model): the result is an estimate, and
the only real figure is a DWT cycle count on a vehicle. Writes ``benchmarks/results/onboard_cost.json``
(the default checkpoint) or ``onboard_cost_<checkpoint's file stem>.json``.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path

from _common import write_result

from datt.configuration import compose
from datt.control.datt import DattController
from datt.export import export_spec, record_rollout, write_c
from datt.export.harness import (
    M4_FLAGS,
    M4_GCC,
    build_m4_timing,
    flags_at,
    instructions_per_call,
    toolchain_missing,
    vectors_h,
    write_harness,
)

CLOCK_HZ = 168e6
PUBLISHED_CYCLES_PER_MAC = {"generic C": 743e-6 * CLOCK_HZ / 13696, "CMSIS-DSP": 478e-6 * CLOCK_HZ / 13696,
                            "hand-optimised": 293e-6 * CLOCK_HZ / 13696}  # fmt: skip


def compile_object(src: Path, opt: str) -> Path:
    obj = src.with_name(f"policy{opt}.o")
    subprocess.run([M4_GCC, *flags_at(opt), *M4_FLAGS, "-fstack-usage", "-c", "-o", str(obj), str(src)], check=True)
    return obj


def size(obj: Path) -> dict:
    out = subprocess.run(["arm-none-eabi-size", str(obj)], check=True, capture_output=True, text=True).stdout
    text, data, bss = (int(x) for x in out.splitlines()[1].split()[:3])
    return {"flash_bytes": text + data, "static_ram_bytes": data + bss}


def stack(obj: Path) -> dict:
    frames = {}
    for line in obj.with_suffix(".su").read_text().splitlines():
        where, nbytes, _ = line.split("\t")
        frames[where.rsplit(":", 1)[-1]] = int(nbytes)

    def f(name):
        return frames.get(name, 0)  # inlined functions have no frame of their own

    act = f("datt_act") + max(
        f("datt_observe") + f("rotate_inverse"), f("datt_network") + max(f("linear"), f("conv1d_relu"))
    )
    return {"datt_act_stack_bytes": act, "datt_l1_step_stack_bytes": f("datt_l1_step"), "frames": frames}


def hot_loop_cpi(obj: Path) -> dict:
    """Cycles per instruction of ``linear``'s inner loop, from its disassembly (two bounds)."""
    dis = subprocess.run(
        ["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", str(obj)], check=True, capture_output=True, text=True
    ).stdout
    body = dis.split("<linear>:", 1)[1].split("\n\n", 1)[0]
    rows = [re.match(r"\s*([0-9a-f]+):\s+(\S+)\s*(.*)", line) for line in body.splitlines()]
    rows = [(int(m.group(1), 16), m.group(2), m.group(3)) for m in rows if m]
    loops = []
    for addr, op, args in rows:
        target = re.match(r"([0-9a-f]+) <", args)
        if op.startswith("b") and target and int(target.group(1), 16) < addr:
            loops.append([r for r in rows if int(target.group(1), 16) <= r[0] <= addr])
    # the innermost loop that multiplies: the shortest backward-branch span with a multiply in it
    # (at -Os GCC uses VMLA, a multiply-accumulate that rounds the product as VMUL + VADD do)
    multiplies = ("vmul", "vmla", "vfma")
    loop = min((rs for rs in loops if any(op.startswith(multiplies) for _, op, _ in rs)), key=len)
    ops = [op for _, op, _ in loop]
    loads = sum(op.startswith("vld") for op in ops)
    vmla = sum(op.startswith(("vmla", "vfma")) for op in ops)
    # Cortex-M4 TRM: VLDR 2 cycles (1 when pipelined after another load), VMLA/VFMA 3, VMUL/VADD
    # and integer ops 1, a taken branch 1 + 2 for the pipeline refill
    worst = len(ops) + loads + 2 * vmla + 2
    best = len(ops) + 1 + 2 * vmla + 2
    return {"instructions": len(ops), "vldr": loads, "vmla": vmla, "vmul": ops.count("vmul.f32"),
            "vadd": ops.count("vadd.f32"), "cpi_low": best / len(ops), "cpi_high": worst / len(ops)}  # fmt: skip


def main() -> None:
    missing = toolchain_missing()
    if missing:
        sys.exit(f"onboard_cost: {missing}")
    cfg = compose("export", sys.argv[1:])
    spec, controller, merged = export_spec(cfg)
    n_macs = spec.macs
    results = {"checkpoint": str(cfg.checkpoint), "macs_per_step": n_macs, "params": int(
        sum(w.size + b.size for w, b in [*spec.convs, spec.proj, *spec.mlp, spec.head]))}  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        write_c(spec, out)
        rec = record_rollout(merged, DattController(controller.actor, frozen=False), num_envs=1, steps=3)
        obs = {k: getattr(rec, k)[-1] for k in ("pos_m", "vel_mps", "quat", "ref_m", "d_hat", "cmd_hist")}
        write_harness(out, vectors_h(obs, rec.action[:, 0], rec.vel_after[:, 0], rec.quat_after[:, 0]))
        for opt in ("-Os", "-O2"):
            obj = compile_object(out / "datt_policy.c", opt)
            act_instr, l1_instr = instructions_per_call(build_m4_timing(out, opt))
            cpi = hot_loop_cpi(obj)
            row = {**size(obj), **stack(obj), "hot_loop": cpi, "datt_act_instructions": act_instr,
                   "datt_l1_step_instructions": l1_instr}  # fmt: skip
            lo, hi = act_instr * cpi["cpi_low"], act_instr * cpi["cpi_high"]
            row["datt_act_cycles_estimate"] = [round(lo), round(hi)]
            row["datt_act_ms_estimate"] = [round(lo / CLOCK_HZ * 1e3, 3), round(hi / CLOCK_HZ * 1e3, 3)]
            results[opt] = row
            print(
                f"{opt}: flash {row['flash_bytes']} B, static RAM {row['static_ram_bytes']} B, stack datt_act "
                f"{row['datt_act_stack_bytes']} B / l1 {row['datt_l1_step_stack_bytes']} B; datt_act "
                f"{act_instr} instructions ({act_instr / n_macs:.1f} per MAC), est. {lo:.0f}-{hi:.0f} cycles = "
                f"{row['datt_act_ms_estimate'][0]}-{row['datt_act_ms_estimate'][1]} ms at 168 MHz; "
                f"datt_l1_step {l1_instr} instructions"
            )
    results["published_rate_estimate_ms"] = {
        name: round(n_macs * cpm / CLOCK_HZ * 1e3, 3) for name, cpm in PUBLISHED_CYCLES_PER_MAC.items()
    }
    print(f"{n_macs} MACs, {results['params']} parameters; at the published cycles per MAC: "
          + ", ".join(f"{k} {v} ms" for k, v in results["published_rate_estimate_ms"].items()))  # fmt: skip
    # the shipped policy's figures keep their file; another checkpoint's go beside them
    stem = Path(str(cfg.checkpoint)).stem
    name = "onboard_cost" if stem == Path(str(compose("export").checkpoint)).stem else f"onboard_cost_{stem}"
    print(f"wrote {write_result(name, results)}")


if __name__ == "__main__":
    main()
