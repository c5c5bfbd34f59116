#!/usr/bin/env python3
"""Slices an STL with CuraEngine 4.13 as the Cura 4.13 front end would for a machine it knows.

CuraEngine alone reads only each setting's `default_value`; the Cura application evaluates the
`value` formulas of the definitions and the machine's default quality, material and nozzle profiles
and sends every setting to the engine. This script does that part of the front end:

  * the setting stack, highest first: the machine's default global quality profile
    (preferred_quality_type), the material-specific quality profile, the default material
    (preferred_material, its print/bed/standby temperatures and diameter), the default nozzle
    variant (preferred_variant_name), the extruder definition chain, the machine definition chain
    down to fdmprinter.def.json (a child definition's properties replace its parent's; a setting's
    `value` formula wins over its `default_value`, as in Cura);
  * formulas evaluated as Cura does, with its functions (extruderValue, extruderValues,
    resolveOrValue, anyExtruderWithMaterial, anyExtruderNrWithOrDefault, defaultExtruderPosition;
    one extruder) and `math`;
  * `{setting}` tokens in machine_start_gcode / machine_end_gcode replaced by their values, as
    Cura's StartSliceJob does (e.g. creality_base's end code `G1 X0 Y{machine_depth}`);
  * every setting passed to `CuraEngine slice` with -s (global) and again after -e0 (extruder 0).

The part is loaded as is (-l): CuraEngine adds half the bed (machine_center_is_zero = false), so a
part centred on x = y = 0 lands on the bed centre, where Cura's arrange puts a single part.

Usage: cura_slice.py RESOURCES MACHINE MODEL.stl OUT.gcode [--settings-out FILE] [-s key=value ...]
  RESOURCES  Cura's resources folder (definitions/, extruders/, quality/, variants/, materials/)
  MACHINE    definition id, e.g. creality_ender3
  -s         extra overrides after the front-end evaluation (none are used for the corpus)
"""

import argparse
import ast
import configparser
import json
import math
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET


def load_definition(res, sub, name):
    """The definition chain of `name`, child first: [(id, json)]."""
    chain = []
    while name:
        with open(os.path.join(res, sub, name + ".def.json"), encoding="utf-8") as f:
            d = json.load(f)
        chain.append((name, d))
        name = d.get("inherits")
        sub = sub if os.path.exists(os.path.join(res, sub, f"{name}.def.json")) else "definitions"
    return chain


def flatten_settings(tree, out):
    for key, prop in tree.items():
        out[key] = dict(prop)
        out[key].pop("children", None)
        if "children" in prop:
            flatten_settings(prop["children"], out)


def merged_definitions(chain):
    """Setting key -> merged properties: the root's settings tree, then each child's overrides."""
    props = {}
    for _, d in reversed(chain):
        if "settings" in d:
            flat = {}
            flatten_settings(d["settings"], flat)
            for k, p in flat.items():
                props.setdefault(k, {}).update(p)
        for k, p in d.get("overrides", {}).items():
            props.setdefault(k, {}).update(p)
    return props


def read_inst(path):
    cp = configparser.RawConfigParser(interpolation=None, strict=False)
    cp.optionxform = str
    cp.read(path, encoding="utf-8")
    return cp


def find_inst(res, sub, pred):
    for root, _, files in os.walk(os.path.join(res, sub)):
        for f in sorted(files):
            if f.endswith(".inst.cfg"):
                cp = read_inst(os.path.join(root, f))
                if pred(cp):
                    return os.path.join(root, f), cp
    return None, None


# Cura's XmlMaterialProfile: material XML setting names -> setting keys (the ones generic PLA uses).
MATERIAL_KEYS = {
    "print temperature": "default_material_print_temperature",
    "heated bed temperature": "default_material_bed_temperature",
    "standby temperature": "material_standby_temperature",
    "print cooling": "cool_fan_speed",
    "retraction amount": "retraction_amount",
    "retraction speed": "retraction_speed",
    "adhesion tendency": "material_adhesion_tendency",
    "surface energy": "material_surface_energy",
    "build volume temperature": "build_volume_temperature",
}


def material_values(res, base_name, diameter):
    """The generic (machine-independent) settings of the material `base_name` for `diameter`."""
    ns = {"m": "http://www.ultimaker.com/material"}
    for f in sorted(os.listdir(os.path.join(res, "materials"))):
        if not f.endswith(".xml.fdm_material") or not f.startswith(base_name):
            continue
        root = ET.parse(os.path.join(res, "materials", f)).getroot()
        d = float(root.find("m:properties/m:diameter", ns).text)
        if abs(d - diameter) > 0.3:  # Cura's 1.75 / 2.85 split
            continue
        values = {"material_diameter": d}
        for s in root.findall("m:settings/m:setting", ns):  # direct children only: not the per-machine ones
            key = MATERIAL_KEYS.get(s.get("key"))
            if key:
                values[key] = s.text
        return f, values
    raise SystemExit(f"no material {base_name} for {diameter} mm filament")


class Stack:
    def __init__(self, props, layers):
        self.props = props  # key -> merged definition properties
        self.layers = layers  # [(name, {key: raw value or '=formula'})], highest first
        self.cache = {}
        self.busy = set()
        self.errors = []

    def typed(self, key, raw):
        t = self.props.get(key, {}).get("type")
        if not isinstance(raw, str):
            return raw
        if t == "float":
            return float(raw)
        if t == "int":
            return int(float(raw))
        if t == "bool":
            return raw.strip() in ("True", "true", "yes", "on", "1")
        if t in ("polygon", "polygons", "[int]"):
            return ast.literal_eval(raw) if raw.strip() else []
        return raw

    def value(self, key):
        if key in self.cache:
            return self.cache[key]
        if key in self.busy:
            raise RecursionError(f"loop at {key}")
        self.busy.add(key)
        try:
            v = self._value(key)
        finally:
            self.busy.discard(key)
        self.cache[key] = v
        return v

    def _value(self, key):
        for _, layer in self.layers:
            if key in layer:
                raw = layer[key]
                if isinstance(raw, str) and raw.startswith("="):
                    return self.typed(key, self.evaluate(key, raw[1:]))
                return self.typed(key, raw)
        p = self.props.get(key)
        if p is None:
            raise KeyError(key)
        if "value" in p:
            try:
                return self.typed(key, self.evaluate(key, p["value"]))
            except Exception as e:  # noqa: BLE001 - reported, then the engine's default
                self.errors.append(f"{key}: {p['value']!r}: {e}")
        return p.get("default_value")

    def evaluate(self, key, expr):
        if not isinstance(expr, str):
            return expr
        tree = ast.parse(expr.strip(), mode="eval")
        names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        g = {"__builtins__": __builtins__, "math": math}
        g.update(self.functions())
        for n in names:
            if n in self.props:
                g[n] = self.value(n)
        return eval(compile(tree, key, "eval"), g)  # noqa: S307 - Cura's own formulas

    def functions(self):
        v = self.value
        return {
            "extruderValue": lambda extruder, key: v(key),
            "extruderValues": lambda key: [v(key)],
            "resolveOrValue": v,
            "anyExtruderWithMaterial": lambda key: bool(v(key)),
            "anyExtruderNrWithOrDefault": lambda key: 0,
            "defaultExtruderPosition": lambda: "0",
            "valueFromContainer": lambda index: None,
            "extruderValueFromContainer": lambda extruder, key, index: v(key),
        }


def expand_tokens(text, stack):
    """Cura's _expandGcodeTokens: {key} and {key, extruder} become the setting's value."""

    def sub(m):
        key = m.group(1)
        if key in stack.props:
            return str(stack.value(key))
        return m.group(0)

    return re.sub(r"\{\s*(\w+)\s*(?:,\s*-?\d+\s*)?\}", sub, text)


def engine_string(value):
    return str(value)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("resources")
    ap.add_argument("machine")
    ap.add_argument("model")
    ap.add_argument("out")
    ap.add_argument("--settings-out")
    ap.add_argument("--engine", default="CuraEngine")
    ap.add_argument("-s", dest="extra", action="append", default=[])
    a = ap.parse_args()
    res = a.resources

    machine_chain = load_definition(res, "definitions", a.machine)
    meta = {}
    for _, d in reversed(machine_chain):
        meta.update(d.get("metadata", {}))
    extruder_id = meta["machine_extruder_trains"]["0"]
    extruder_chain = load_definition(res, "extruders", extruder_id)
    # Global settings from the machine chain; the extruder chain overrides its own keys.
    props = merged_definitions(machine_chain)
    for k, p in merged_definitions(extruder_chain).items():
        props.setdefault(k, {}).update(p)
    engine_defaults = {k: p.get("default_value") for k, p in props.items() if p.get("type") != "category"}

    # Which definition the profiles are written for: the machine's quality_definition (else itself).
    qdef = meta.get("quality_definition", a.machine)
    quality_type = meta.get("preferred_quality_type", "normal")
    nozzle_name = meta.get("preferred_variant_name")
    material_base = meta.get("preferred_material", "generic_pla")

    layers = []
    _, q = find_inst(res, "quality", lambda cp: cp.get("general", "definition", fallback="") == qdef
                     and cp.get("metadata", "quality_type", fallback="") == quality_type
                     and cp.get("metadata", "global_quality", fallback="") == "True")
    if q is None:
        raise SystemExit(f"no global {quality_type} quality for {qdef}")
    layers.append(("quality " + q.get("general", "name"), dict(q["values"]) if q.has_section("values") else {}))
    variant = {}
    vname = None
    if nozzle_name:
        _, v = find_inst(res, "variants", lambda cp: cp.get("general", "definition", fallback="") == qdef
                         and cp.get("general", "name", fallback="") == nozzle_name)
        if v is not None:
            variant = dict(v["values"])
            vname = nozzle_name
    diameter = float(Stack(props, [("variant", variant)]).value("material_diameter"))
    mfile, material = material_values(res, material_base, diameter)
    mat_type = "PLA" if "pla" in material_base.lower() else None
    _, mq = find_inst(res, "quality", lambda cp: cp.get("general", "definition", fallback="") == qdef
                      and cp.get("metadata", "quality_type", fallback="") == quality_type
                      and cp.get("metadata", "material", fallback="") == material_base
                      and cp.get("metadata", "variant", fallback="") == (vname or ""))
    if mq is not None and mq.has_section("values"):
        layers.append(("quality (material) " + mq.get("general", "name"), dict(mq["values"])))
    layers.append((f"material {mfile}", material))
    if vname:
        layers.append((f"variant {vname}", variant))
    del mat_type

    stack = Stack(props, layers)
    settings = {}
    for key, p in props.items():
        if p.get("type") == "category" or "default_value" not in p and "value" not in p:
            continue
        try:
            settings[key] = stack.value(key)
        except Exception as e:  # noqa: BLE001
            stack.errors.append(f"{key}: {e}")
    for key in ("machine_start_gcode", "machine_end_gcode"):
        settings[key] = expand_tokens(settings[key], stack)
    for kv in a.extra:
        k, _, v = kv.partition("=")
        settings[k] = v

    if a.settings_out:
        with open(a.settings_out, "w", encoding="utf-8") as f:
            f.write(f"# CuraEngine settings that differ from the definitions' default_value ({a.machine}),\n")
            f.write("# as cura_slice.py evaluated them; the profiles: " + "; ".join(os.path.basename(n) for n, _ in layers) + "\n")
            for k in sorted(settings):
                if engine_string(settings[k]) != engine_string(engine_defaults.get(k)):
                    f.write(f"{k} = {json.dumps(settings[k]) if isinstance(settings[k], str) else settings[k]}\n")
    for e in stack.errors:
        print(f"cura_slice.py: formula not evaluated, engine default used: {e}", file=sys.stderr)

    env = dict(os.environ)
    env["CURA_ENGINE_SEARCH_PATH"] = ":".join(os.path.join(res, d) for d in ("definitions", "extruders"))
    args = [a.engine, "slice", "-j", os.path.join(res, "definitions", a.machine + ".def.json")]
    pairs = [f"{k}={engine_string(v)}" for k, v in sorted(settings.items())]
    for kv in pairs:
        args += ["-s", kv]
    args += ["-e0"]
    for kv in pairs:
        args += ["-s", kv]
    # CuraEngine writes the mesh's path into ;MESH: comments: give it the file name, as Cura does.
    args += ["-l", os.path.basename(a.model), "-o", os.path.abspath(a.out)]
    r = subprocess.run(args, env=env, cwd=os.path.dirname(os.path.abspath(a.model)), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.stderr.write(r.stderr[-4000:])
        raise SystemExit(f"CuraEngine failed ({r.returncode})")


if __name__ == "__main__":
    main()
