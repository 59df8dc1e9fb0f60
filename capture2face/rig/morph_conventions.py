"""Morph conventions other than ARKit's, and how the clip's 52 ARKit curves drive them.

A character without ARKit-named morphs often carries another tool's set: Oculus / Ready
Player Me visemes (``viseme_aa``), Ready Player Me's legacy ``mouthOpen`` / ``mouthSmile``,
VRM 0.x blend-shape presets (``A``, ``Blink_L``, ``Joy``), VRM 1.0 expressions (``aa``,
``blinkLeft``, ``happy``) or the Rocketbox expression set (``h_expressions.AE_AA_h``).
:data:`RECIPES` is the one table: for each name, a recipe over the ARKit curves

    weight = clip(sum of terms, 0, 1),  a term = coefficient * factor * factor * ...

where a factor is an ARKit curve (``jawOpen``), a derived channel of :data:`DERIVED`
(``smile``: both corners' mean), ``~x`` (1 - x) or ``has(name)`` (1 when the character has
a morph the table knows by that name, else 0: a one-eye blink gives way to a
both-eyes one). The mouth's opening is split between the visemes by the lips' shape
(``aa`` open, ``O`` round and open, ``E`` spread and half open), so the mouth opens once,
not once per viseme; a wide-open jaw is ``aa`` whatever the corners do, joined past half
open by ``O`` (a viseme set's widest mouth is its open shapes together). Sides are the
character's own, as ARKit's (``Blink_L``: ``eyeBlinkLeft``; Rocketbox's ``R...``:
``...Right``).

A character with any ARKit-named morph is driven by those alone (its visemes stay 0, as
before): the conventions drive characters that have no ARKit name.

VRM expression rules (``FaceRig.morph_rules``, from :mod:`capture2face.gltf.vrm`) apply
after the recipes: ``isBinary`` (on above 0.5), then VRM 1.0's ``overrideBlink`` /
``overrideLookAt`` / ``overrideMouth`` (``block``: the group is 0 while the expression is
on; ``blend``: scaled by 1 - its weight).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from capture2face.topology import ARKIT_NAMES


def _mean(*names: str):
    return lambda c: sum(c[n] for n in names) / len(names)


#: Derived channels a recipe may name: {name: (how, function of the curve dict)}.
DERIVED = {
    "smile": ("mean of mouthSmileLeft/Right", _mean("mouthSmileLeft", "mouthSmileRight")),
    "stretch": ("mean of mouthStretchLeft/Right", _mean("mouthStretchLeft", "mouthStretchRight")),
    "press": ("mean of mouthPressLeft/Right", _mean("mouthPressLeft", "mouthPressRight")),
    "frown": ("mean of mouthFrownLeft/Right", _mean("mouthFrownLeft", "mouthFrownRight")),
    "browDown": ("mean of browDownLeft/Right", _mean("browDownLeft", "browDownRight")),
    "browOuterUp": ("mean of browOuterUpLeft/Right", _mean("browOuterUpLeft", "browOuterUpRight")),
    "eyeWide": ("mean of eyeWideLeft/Right", _mean("eyeWideLeft", "eyeWideRight")),
    "eyeSquint": ("mean of eyeSquintLeft/Right", _mean("eyeSquintLeft", "eyeSquintRight")),
    "cheekSquint": ("mean of cheekSquintLeft/Right", _mean("cheekSquintLeft", "cheekSquintRight")),
    "noseSneer": ("mean of noseSneerLeft/Right", _mean("noseSneerLeft", "noseSneerRight")),
    "spread": ("max of smile, stretch", lambda c: np.maximum(c["smile"], c["stretch"])),
    "round": ("max of mouthFunnel, mouthPucker", lambda c: np.maximum(c["mouthFunnel"], c["mouthPucker"])),
    # A spread mouth is a half-open shape (E): the jaw's opening goes to it up to half open,
    # then back to the open shape (aa), so a wide-open scream with its corners pulled is aa.
    "spreadOpen": ("jawOpen * min(1, 2 (1 - jawOpen)) * spread",
                   lambda c: c["jawOpen"] * np.minimum(1.0, 2.0 * (1.0 - c["jawOpen"])) * c["spread"]),
    # Past half open the round-open shape joins the open one: a viseme set's widest mouth is
    # its open shapes together (Ready Player Me's viseme_aa alone drops the jaw 1.6 cm, with
    # viseme_O 3.9 cm, as far as its jawOpen).
    "wide": ("max(0, 2 jawOpen - 1) * (1 - round)",
             lambda c: np.maximum(0.0, 2.0 * c["jawOpen"] - 1.0) * (1.0 - c["round"])),
    "blinkBoth": ("min of eyeBlinkLeft/Right", lambda c: np.minimum(c["eyeBlinkLeft"], c["eyeBlinkRight"])),
    "duchenne": ("smile * max(cheekSquint, eyeSquint), a smile that reaches the eyes",
                 lambda c: c["smile"] * np.maximum(c["cheekSquint"], c["eyeSquint"])),
    "lookUp": ("mean of eyeLookUpLeft/Right", _mean("eyeLookUpLeft", "eyeLookUpRight")),
    "lookDown": ("mean of eyeLookDownLeft/Right", _mean("eyeLookDownLeft", "eyeLookDownRight")),
    # The character's own left: its left eye looks out, its right eye in.
    "lookLeft": ("mean of eyeLookOutLeft, eyeLookInRight", _mean("eyeLookOutLeft", "eyeLookInRight")),
    "lookRight": ("mean of eyeLookOutRight, eyeLookInLeft", _mean("eyeLookOutRight", "eyeLookInLeft")),
}

# Shared by the viseme-like sets: the jaw's opening split by the lips' shape.
_OPEN = "jawOpen*~round - spreadOpen*~round"
_ROUND_OPEN = "mouthFunnel*~mouthPucker"
_ROUND_OR_WIDE = _ROUND_OPEN + " + wide"
_SPREAD_OPEN = "spreadOpen*~round"
_SPREAD_CLOSED = "stretch*~jawOpen"
_BLINK_L = "eyeBlinkLeft - blinkBoth*has({both})"
_BLINK_R = "eyeBlinkRight - blinkBoth*has({both})"


def _vrm(a, i, u, e, o, joy, angry, sorrow, fun, surprised, blink, blink_l, blink_r, neutral, look) -> dict:
    """A VRM preset set by its names (VRM 0.x and 1.0 name the same presets differently)."""
    return {
        # I spreads the mouth for a smile too: a VRM's feelings (Joy, Fun) hardly widen it
        # (Godette's Fun 0.016 IOD, Joy none, its I 0.076; a human's smile 0.079).
        a: _OPEN, i: "spread*~jawOpen", u: "mouthPucker", e: _SPREAD_OPEN, o: _ROUND_OR_WIDE,
        # The feelings that shape the mouth give way to speech (VRM 0.x has no override rules).
        joy: "duchenne*~jawOpen", angry: "0.5*browDown + 0.5*noseSneer", sorrow: "browInnerUp*~browOuterUp*~smile",
        fun: "smile*~jawOpen - duchenne*~jawOpen", surprised: "browOuterUp*eyeWide + 0.5*browOuterUp*jawOpen",
        blink: "blinkBoth", blink_l: _BLINK_L.format(both=blink), blink_r: _BLINK_R.format(both=blink),
        neutral: "0", look[0]: "lookUp", look[1]: "lookDown", look[2]: "lookLeft", look[3]: "lookRight",
    }


def _rocketbox() -> dict:
    """Rocketbox's head (``h_expressions.*``) and teeth (``h_teeth.t_*``) sets: the same
    recipe moves both (the teeth follow the jaw)."""
    head = {
        "AE_AA_h": _OPEN, "AO_a_h": "0", "Ax_E_h": _SPREAD_OPEN, "TD_I_h": _SPREAD_CLOSED,
        "UH_OO_h": _ROUND_OR_WIDE, "UW_U_h": "0", "H_EST_h": "0", "FV_h": "mouthRollLower*~jawOpen", "S_h": "0",
        "SH_CH_h": "0", "MPB_Up_h": "mouthRollUpper", "MPB_Down_h": "press*~jawOpen", "KG_h": "0",
        "JawCompress_h": "0", "JawFront_h": "jawForward", "Chew_h": "0", "MouthOpen_h": "0", "Shout_h": "0",
        "Kiss_h": "mouthPucker", "Chin_h": "mouthShrugLower", "Glotis_h": "0",
        "Rjaw_h": "jawRight", "Ljaw_h": "jawLeft",
    }
    teeth = {"t_" + k: v for k, v in head.items() if k not in ("Kiss_h", "Chin_h", "Glotis_h", "MPB_Up_h",
                                                                 "MPB_Down_h")}
    teeth["t_MPB_h"] = "0"
    sided = {
        "lipUp_h": "mouthUpperUp{S}", "lipDown_h": "mouthLowerDown{S}", "lipSide_h": "mouth{S}",
        "lipCorner_h": "mouthStretch{S}", "smileClose_h": "mouthSmile{S}", "smileOpen_h": "0",
        "mouthSad_h": "mouthFrown{S}", "disgust_h": "noseSneer{S}", "blow_h": "cheekPuff",
        "neckTension_h": "0", "nostril_h": "0", "eyeClose_h": "eyeBlink{S}", "eyeOpen_h": "eyeWide{S}",
        "squint_h": "eyeSquint{S}", "lowLid_h": "cheekSquint{S}", "sad_h": "0", "pityful_h": "0",
        "browUp_h": "browInnerUp",
        "RbrowUp_h": "browOuterUp{S}", "browDown_h": "browDown{S}", "RbrowDown_h": "browDown{S}",
    }
    for side, word in (("R", "Right"), ("L", "Left")):
        for k, v in sided.items():
            # "RbrowUp_h" above is the outer brow: Rocketbox spells it "RRbrowUp_h" / "LLbrowUp_h".
            key = side + side + k[1:] if k.startswith("R") else side + k
            head[key] = v.format(S=word)
    return {**head, **teeth}


#: {convention: {morph name: recipe}}; names match in any case, after any ``prefix.``.
RECIPES: dict[str, dict[str, str]] = {
    "Oculus / Ready Player Me visemes": {
        "viseme_sil": "0", "viseme_aa": _OPEN, "viseme_O": _ROUND_OR_WIDE, "viseme_U": "mouthPucker",
        "viseme_E": _SPREAD_OPEN, "viseme_I": _SPREAD_CLOSED, "viseme_PP": "press*~jawOpen",
        "viseme_FF": "mouthRollLower*~jawOpen", "viseme_TH": "0", "viseme_DD": "0", "viseme_kk": "0",
        "viseme_CH": "0", "viseme_SS": "0", "viseme_nn": "0", "viseme_RR": "0",
    },
    "Ready Player Me legacy": {"mouthOpen": "jawOpen", "mouthSmile": "smile"},
    "VRM 0.x presets": _vrm("a", "i", "u", "e", "o", "joy", "angry", "sorrow", "fun", "surprised", "blink",
                            "blink_l", "blink_r", "neutral", ("lookup", "lookdown", "lookleft", "lookright")),
    "VRM 1.0 presets": _vrm("aa", "ih", "ou", "ee", "oh", "happy", "angry", "sad", "relaxed", "surprised", "blink",
                            "blinkLeft", "blinkRight", "neutral", ("lookUp", "lookDown", "lookLeft", "lookRight")),
    "Rocketbox": _rocketbox(),
}

_KEYS: dict[str, tuple[str, str]] = {}  # lower-case name -> (convention, name as the table spells it)
for _conv, _table in RECIPES.items():
    for _name in _table:
        _KEYS.setdefault(_name.lower(), (_conv, _name))

_TERM = re.compile(r"\s*([+-])?\s*(?:(\d+(?:\.\d*)?)\*)?([^+-]+)")
_HAS = re.compile(r"has\((\w+)\)")


@dataclass(frozen=True)
class Term:
    """coefficient * product of factors: (curve or derived name, complemented)."""

    coefficient: float
    factors: tuple[tuple[str, bool], ...]
    needs: tuple[str, ...]  # has(name): morphs the term needs in the character


def parse_recipe(recipe: str) -> list[Term]:
    """The terms of a recipe string (the module docs' grammar); ``"0"``: none."""
    terms = []
    text = recipe.strip()
    if text in ("", "0"):
        return terms
    for sign, coef, body in _TERM.findall(text):
        factors, needs = [], []
        for f in body.strip().split("*"):
            f = f.strip()
            m = _HAS.fullmatch(f)
            if m:
                needs.append(m.group(1))
                continue
            name = f.lstrip("~")
            if name not in DERIVED and name not in ARKIT_NAMES:
                raise ValueError(f"recipe {recipe!r}: unknown channel {name!r}")
            factors.append((name, f.startswith("~")))
        terms.append(Term((-1.0 if sign == "-" else 1.0) * float(coef or 1.0), tuple(factors), tuple(needs)))
    return terms


def convention_key(name: str) -> tuple[str, str] | None:
    """(convention, table name) of a morph name, or None: any case, after any ``prefix.``."""
    text = str(name).strip()
    return _KEYS.get(text.lower()) or _KEYS.get(text.rsplit(".", 1)[-1].lower())


def convention_morphs(morph_names: list[str]) -> dict[int, tuple[str, str]]:
    """{morph index: (convention, table name)} of every morph the table knows."""
    keys = {i: convention_key(n) for i, n in enumerate(morph_names)}
    return {i: k for i, k in keys.items() if k is not None}


def _channels(arkit_names: list[str], curves: np.ndarray) -> dict[str, np.ndarray]:
    """{ARKit or derived name: (F,) curve}; ARKit names the clip lacks are 0."""
    curves = np.asarray(curves, np.float32)
    index = {n: i for i, n in enumerate(arkit_names)}
    zero = np.zeros(len(curves), np.float32)
    c = {n: (curves[:, index[n]] if n in index else zero) for n in ARKIT_NAMES}
    for name, (_, fn) in DERIVED.items():  # in order: later ones read earlier ones
        c[name] = np.asarray(fn(c), np.float32)
    return c


def convention_weights(arkit_names: list[str], arkit_curves: np.ndarray, morph_names: list[str]) -> np.ndarray:
    """(F, M) float32 weights of the morphs :data:`RECIPES` knows, from the clip's ARKit
    curves (F, S) named ``arkit_names``; other morphs 0."""
    known = convention_morphs(morph_names)
    out = np.zeros((len(arkit_curves), len(morph_names)), np.float32)
    if not known:
        return out
    c = _channels(arkit_names, arkit_curves)
    present = {name.lower() for _, name in known.values()}
    for m, (conv, name) in known.items():
        total = np.zeros(len(arkit_curves), np.float32)
        for term in parse_recipe(RECIPES[conv][name]):
            if not all(n.lower() in present for n in term.needs):
                continue
            value = np.full(len(arkit_curves), term.coefficient, np.float32)
            for f, complement in term.factors:
                value = value * (1.0 - c[f] if complement else c[f])
            total += value
        out[:, m] = total
    return np.clip(out, 0.0, 1.0)


def recipe_poses(morph_names: list[str]) -> np.ndarray:
    """(52, M) float32 the head's morph weights at each ARKit curve alone at 1 (rows in
    :data:`~capture2face.topology.ARKIT_NAMES` order): what each curve's recipe makes."""
    return convention_weights(list(ARKIT_NAMES), np.eye(len(ARKIT_NAMES), dtype=np.float32), morph_names)


def convention_channels(morph_names: list[str]) -> dict[int, tuple[str, ...]]:
    """{morph index: the ARKit curves that alone turn it on} of every morph :data:`RECIPES`
    knows with a recipe other than ``"0"`` (``viseme_aa``: ``jawOpen``; Rocketbox's
    ``LbrowDown_h``: ``browDownLeft``; ``Joy``, a smile with the eyes: none alone). The
    solve (:mod:`capture2face.retarget.arkit_solve`) treats a morph whose curves are one
    ARKit name as that name (curve-only, antagonists)."""
    known = convention_morphs(morph_names)
    live = [m for m, (conv, name) in known.items() if parse_recipe(RECIPES[conv][name])]
    if not live:
        return {}
    alone = recipe_poses(morph_names)
    return {m: tuple(ARKIT_NAMES[k] for k in np.flatnonzero(alone[:, m] > 0)) for m in live}


def convention_recipes(morph_names: list[str]) -> dict[int, str]:
    """{morph index: its recipe} of every morph :data:`RECIPES` knows (Rocketbox's teeth
    ``t_AE_AA_h`` share the head's ``AE_AA_h``: the solve moves them together)."""
    return {m: RECIPES[conv][name] for m, (conv, name) in convention_morphs(morph_names).items()}


#: Conventions authored as a mix, one shape at a time blended across transitions (Oculus
#: visemes sum to 1): several lips' shapes at once overdrive the mesh (docs/characters.md).
MIXES = ("Oculus / Ready Player Me visemes",)


def mix_morphs(morph_names: list[str]) -> np.ndarray:
    """(G,) indices of the lips' shapes of a :data:`MIXES` convention: its morphs but those
    the jaw's opening alone turns on (``aa``, joined by ``O`` past half open: a viseme
    set's widest mouth is its open shapes together)."""
    known = convention_morphs(morph_names)
    jaw = recipe_poses(morph_names)[ARKIT_NAMES.index("jawOpen")]
    return np.array(sorted(m for m, (conv, _) in known.items() if conv in MIXES and jaw[m] <= 0), np.int64)


# FaceRig.morph_rules columns and codes (VRM expression rules).
RULE_BINARY, RULE_BLINK, RULE_LOOK_AT, RULE_MOUTH, RULE_GROUP = range(5)
OVERRIDE_CODES = {"none": 0, "block": 1, "blend": 2}
#: The groups an override acts on, by rule column: the presets (VRM 1.0 and 0.x) in each.
GROUPS = {
    RULE_BLINK: ("blink", "blinkleft", "blinkright", "blink_l", "blink_r"),
    RULE_LOOK_AT: ("lookup", "lookdown", "lookleft", "lookright"),
    RULE_MOUTH: ("aa", "ih", "ou", "ee", "oh", "a", "i", "u", "e", "o"),
}


#: A VRM head's both-eyes blink and its one-eye blinks (VRM 0.x and 1.0 names): the two
#: close the same lid, so an eye's closing is the blink plus its own.
BLINKS = (("blink", "blink_l", "blink_r"), ("blink", "blinkleft", "blinkright"))


def blink_morphs(morph_names: list[str]) -> tuple[int | None, int, int] | None:
    """(both, left, right) morph indices of a VRM's blink and one-eye blinks (:data:`BLINKS`;
    ``both`` None where it has only the one-eye blinks), or None without both of those."""
    known = {name.lower(): m for m, (_, name) in convention_morphs(morph_names).items()}
    return next(((known.get(both), known[left], known[right]) for both, left, right in BLINKS
                 if left in known and right in known), None)


def one_blink(weights: np.ndarray, morph_names: list[str], rules: np.ndarray | None = None) -> np.ndarray:
    """(F, M) weights whose blink and one-eye blinks close each eye at most once: they close
    the same lid, and the recipes' one-eye rest, turned on at 1 by ``isBinary`` on top of
    the blink, took Godette's lids 1.35-1.38 of their way on d3 and d6. Each eye's
    closing (the blink plus its own, at most 1) is split: the blink takes what both eyes
    share and each one-eye blink the rest; where the one-eye blinks are ``isBinary`` in
    ``rules`` (M, 5) (Godette's: on above 0.5, so a rest under half was lost and one over
    it closed the eye past full), the blink takes both eyes' mean, and a wink (one eye
    closing at least half more than the other) its one-eye blink alone."""
    found = blink_morphs(morph_names)
    if found is None or found[0] is None:
        return weights
    b, sides = found[0], list(found[1:])
    closing = np.minimum(weights[:, [b]] + weights[:, sides], 1.0)
    weights = weights.copy()
    if rules is not None and len(rules) and (np.asarray(rules)[sides, RULE_BINARY] > 0).all():
        wink = closing - closing[:, ::-1] >= 0.5
        weights[:, b] = np.where(wink.any(1), 0.0, closing.mean(1))
        weights[:, sides] = wink
    else:
        weights[:, b] = closing.min(1)
        weights[:, sides] = closing - closing.min(1, keepdims=True)
    return weights


def apply_rules(weights: np.ndarray, rules: np.ndarray | None) -> np.ndarray:
    """(F, M) weights with the VRM expression rules (M, 5) int8 applied (the module docs):
    ``isBinary`` first, then each override group scaled by 1 - the largest override
    amount on it (three-vrm's order); None: unchanged."""
    if rules is None or not len(rules):
        return weights
    rules = np.asarray(rules)
    w = np.where(rules[:, RULE_BINARY] > 0, (weights > 0.5).astype(np.float32), weights)
    out = w.copy()
    for column in (RULE_BLINK, RULE_LOOK_AT, RULE_MOUTH):
        block = rules[:, column] == OVERRIDE_CODES["block"]
        blend = rules[:, column] == OVERRIDE_CODES["blend"]
        if not (block.any() or blend.any()):
            continue
        amount = np.zeros(len(w), np.float32)
        if block.any():
            amount = np.maximum(amount, (w[:, block] > 0).any(1).astype(np.float32))
        if blend.any():
            amount = np.maximum(amount, w[:, blend].max(1))
        group = rules[:, RULE_GROUP] == column
        out[:, group] *= (1.0 - np.clip(amount, 0.0, 1.0))[:, None]
    return out
