"""Numbers in words a person reads: plural forms, lists of UAV ids, values that are missing for a reason."""

from __future__ import annotations


def plural(n: int, word: str, many: str | None = None) -> str:
    """``1 send``, ``2 sends``, ``0 entries`` (``many`` for a plural that is not ``word + "s"``)."""
    return f"{n} {word if n == 1 else (many or word + 's')}"


def entries(n: int) -> str:
    return plural(n, "entry", "entries")


def number(v: float | None, fmt: str = ".1f", unit: str = "", missing: str = "not measured") -> str:
    """``v`` with its unit (``12.3 s``), or what stands for it when there is none (``never``, ``not measured``)."""
    if v is None or v != v:
        return missing
    return f"{v:{fmt}}" + (f" {unit}" if unit else "")


def id_list(ids: list[int] | tuple[int, ...]) -> str:
    """``UAV 3``, ``UAVs 3 and 7``, ``UAVs 1, 2 and 5``."""
    ids = list(ids)
    if len(ids) == 1:
        return f"UAV {ids[0]}"
    if not ids:
        return "no UAV"
    return "UAVs " + ", ".join(str(u) for u in ids[:-1]) + f" and {ids[-1]}"


def format_ids(ids: list[int] | set[int]) -> str:
    """UAV ids in runs, as a command line takes them: [1,2,3,7] -> ``1-3,7`` (``-`` for none)."""
    s = sorted(ids)
    parts: list[str] = []
    i = 0
    while i < len(s):
        j = i
        while j + 1 < len(s) and s[j + 1] == s[j] + 1:
            j += 1
        parts.append(str(s[i]) if i == j else f"{s[i]}-{s[j]}")
        i = j + 1
    return ",".join(parts) or "-"


def metres(v: float) -> str:
    """A distance: to the centimetre under 10 m (4.96 m is not 5.0 m next to a 5 m safety distance), else 0.1 m."""
    return f"{v:.2f} m" if abs(v) < 10.0 else f"{v:.1f} m"
