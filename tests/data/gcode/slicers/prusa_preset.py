#!/usr/bin/env python3
"""Flattens one printer preset of a PrusaSlicer vendor bundle (e.g.
/usr/share/PrusaSlicer/profiles/PrusaResearch.ini) into a config file for `prusa-slicer --load`,
with the printer's default print and filament presets, as the GUI would pick them after the
configuration wizard: `inherits = a; b` applies a, then b, then the section's own keys.

Usage: prusa_preset.py BUNDLE.ini "PRINTER PRESET NAME" > preset.ini
"""

import configparser
import sys

# Keys of the bundle's bookkeeping, not print options.
SKIP = {"inherits", "renamed_from", "alias", "default_print_profile", "default_filament_profile", "default_sla_print_profile", "default_sla_material_profile"}


def load(path):
    cp = configparser.RawConfigParser(strict=False, interpolation=None, delimiters=("=",), comment_prefixes=("#",), inline_comment_prefixes=None)
    cp.optionxform = str  # keep the case of keys
    with open(path, encoding="utf-8") as f:
        cp.read_file(f)
    return cp


def resolve(cp, kind, name, seen=()):
    section = f"{kind}:{name}"
    if section not in cp:
        raise SystemExit(f"no [{section}] in the bundle")
    if section in seen:
        raise SystemExit(f"inheritance loop at [{section}]")
    own = dict(cp[section])
    out = {}
    for parent in filter(None, (p.strip() for p in own.get("inherits", "").split(";"))):
        out.update(resolve(cp, kind, parent, seen + (section,)))
    out.update(own)
    return out


def main():
    bundle, printer = sys.argv[1], sys.argv[2]
    cp = load(bundle)
    p = resolve(cp, "printer", printer)
    print_name = p["default_print_profile"]
    filament_name = p["default_filament_profile"]
    merged = {}
    for kind, name in (("print", print_name), ("filament", filament_name), ("printer", printer)):
        for k, v in resolve(cp, kind, name).items():
            if k not in SKIP:
                merged[k] = v
    merged["print_settings_id"] = print_name
    merged["filament_settings_id"] = filament_name
    merged["printer_settings_id"] = printer
    print(f"# {printer} / {print_name} / {filament_name}, flattened from {bundle} by prusa_preset.py")
    for k in sorted(merged):
        print(f"{k} = {merged[k]}")


if __name__ == "__main__":
    main()
