"""The pieces every figures block is written with: a committed JSON read, a markdown table, the provenance line
under a block, percentages and intervals as the docs print them. Shared by ``readme_figures``, ``docs_figures`` and
``verdict_figures``; reads ``benchmarks/results/`` only.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SHIPPED_GENERATOR = "ded63c1c8e7216ae"  # checkpoint_hash of controltac_il/generator/checkpoints/default


def load(name: str) -> dict:
    return json.loads((RESULTS / name).read_text())


def table(header: list[str], rows: list[list]) -> str:
    lines = [header, ["---"] * len(header), *rows]
    return "\n".join("| " + " | ".join(str(c).replace("|", "\\|") for c in line) + " |" for line in lines)


def provenance(name: str, doc: dict, generator: str | None, note: str = "") -> str:
    """The line under a block: where its figures come from, and *History* when no commit reproduces them."""
    commit, date = doc["machine"]["git_commit"], doc["machine"]["date_utc"][:10]
    why = []
    if commit.endswith("-dirty"):
        why.append(f"measured on a dirty tree ({commit.removesuffix('-dirty')} plus uncommitted changes)")
    if generator is not None and generator != SHIPPED_GENERATOR:
        why.append(f"measured with the earlier generator {generator}, not the shipped default {SHIPPED_GENERATOR}")
    where = f"`benchmarks/results/{name}`, commit {commit}, {date}{machine(doc['machine'])}"
    where += f", generator {generator}{note}" if generator else note
    if why:
        return f"*History (not reproducible from committed files): {'; '.join(why)}. Source: {where}.*"
    return f"*Source: {where}.*"


def machine(m: dict) -> str:
    """', on <the CPU> (<cores> cores)[, with <the GPU>]' from a results JSON's ``machine`` record ('' where it names
    neither): the host, whichever of its devices the figures were measured on (the block says which)."""
    cpu = " ".join(str(m.get("cpu") or "").split())
    host = f"{cpu} ({m['cores']} cores)" if cpu and m.get("cores") else cpu
    gpu = m.get("cuda_device")
    host = f"{host}, with {gpu}" if host and gpu else host or gpu or ""
    return f", on {host}" if host else ""


def recorded_generator(doc: dict) -> str | None:
    """The generator hash a results JSON records, wherever its benchmark keeps it; None when it records none."""
    for path in (("generator_hash",), ("settings", "generator_hash"), ("generation", "generator_hash"), ("stage1_hash",),
                 ("settings", "checkpoints", "default", "hash")):
        d = doc
        for k in path:
            d = d.get(k) if isinstance(d, dict) else None
        if d:
            return d
    return None


def source(name: str, doc: dict) -> str:
    """The provenance line of a block whose JSON records its generator where ``recorded_generator`` looks, or none."""
    return provenance(name, doc, recorded_generator(doc))


def pct(x: float) -> int:
    """x as a whole percentage, halves rounded up (the JSONs store intervals rounded to 3-4 digits)."""
    return math.floor(x * 100 + 0.5 + 1e-9)


def ci_points(c: dict) -> str:
    """A comparison's 95 % interval in points: ``[-26.0, +19.2]``."""
    return f"[{c['ci95'][0] * 100:+.1f}, {c['ci95'][1] * 100:+.1f}]"
