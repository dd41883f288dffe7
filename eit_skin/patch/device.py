"""The board a layer is read from: a patch layer's ``device:`` section (docs/patch-schema.md).

A board profile is data: its name, the options it takes (type, default, unit, meaning) and
what it needs of the layer's protocol. The byte formats and host commands that implement a
profile live in :mod:`eit_skin.hardware.boards`; the names and options belong to the schema,
here, so a patch file is validated without importing any hardware code.

Profiles (docs/boards.md has one section each):

* ``eit_skin``: eit_skin's own binary wire protocol (docs/wire-protocol.md); the default.
* ``openeit``: OpenEIT / Mindseye Spectra: ASCII ``magnitudes: v1, ..., vN,`` lines, opposite
  drive, N = n (n - 4) for 8, 16 or 32 electrodes; the host selects the mode.
* ``lines``: a board printing one frame per text line (EIT-kit derivatives, Arduino/ESP32 DIY
  boards): separators, an optional ``label:`` prefix, a value count, dropped zeros.
* ``sciospec``: Sciospec EIT16/32/64 binary frames, single-ended complex potentials per
  injection; the host sends the setup and forms the protocol's differences.
* ``cn0565``: Analog Devices EVAL-CN0565 through ``pyadi-iio`` (optional extra), every
  measurement requested by the host.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from eit_skin.patch.protocol import Protocol, ProtocolSpec


@dataclass(frozen=True)
class DeviceOption:
    """One option of a board profile.

    Attributes:
        name: key in the ``device:`` section.
        kind: ``"int"``, ``"float"``, ``"bool"`` or ``"str"``.
        default: value when the key is absent.
        unit: SI unit or ``""``.
        description: one line for docs/patch-schema.md.
        choices: allowed values, or None for any value of the kind.
        positive: numbers must be > 0.
    """

    name: str
    kind: str
    default: Any
    unit: str
    description: str
    choices: tuple[Any, ...] | None = None
    positive: bool = False


def _baud(default: int) -> DeviceOption:
    return DeviceOption(
        "baud", "int", default, "bit/s", "serial rate (ignored by USB CDC-ACM boards)", None, True
    )


def _ack(default: float, what: str) -> DeviceOption:
    return DeviceOption(
        "ack_timeout_s",
        "float",
        default,
        "s",
        f"time to wait for {what} after the host's commands before an ERROR diagnostic "
        "and a new try",
        None,
        True,
    )


_VOLTS_PER_UNIT = DeviceOption(
    "volts_per_unit",
    "float",
    1.0,
    "V",
    "volts per number the board prints (difference imaging does not need it)",
    None,
    True,
)

NEGATIVE_INPUT_GAIN = DeviceOption(
    "negative_input_gain",
    "float",
    1.0,
    "",
    "gain of the differential input's minus side over its plus side (1: matched; the "
    "model reads V(+) - g V(-) against the sink: docs/patch-schema.md); pair drives only",
    None,
    True,
)
"""The one option every differential-input profile has (Sciospec's host forms differences of
single-ended potentials: no such input); it changes the model (the layer's content hash)."""

PROFILES: dict[str, tuple[DeviceOption, ...]] = {
    "eit_skin": (_baud(921_600), NEGATIVE_INPUT_GAIN),
    "openeit": (
        _baud(115_200),
        _ack(10.0, "a frame of the selected mode"),
        _VOLTS_PER_UNIT,
        NEGATIVE_INPUT_GAIN,
    ),
    "lines": (
        _baud(115_200),
        DeviceOption("separators", "str", ", ;\t", "", "characters that separate values (any mix)"),
        DeviceOption(
            "prefix",
            "str",
            "",
            "",
            "label before the values, e.g. 'magnitudes:' ('' accepts any 'label:' prefix)",
        ),
        DeviceOption(
            "values",
            "int",
            0,
            "",
            "numbers per line (0: the layer's device frame size, or its measurement count "
            "with drop_zeros)",
        ),
        DeviceOption(
            "drop_zeros",
            "bool",
            False,
            "",
            "the board leaves out the full layout's unused (zero) entries",
        ),
        _VOLTS_PER_UNIT,
        DeviceOption(
            "start_command",
            "str",
            "",
            "",
            "text the host sends on every connect (a newline is appended), '' for none",
        ),
        _ack(10.0, "the first good frame"),
        NEGATIVE_INPUT_GAIN,
    ),
    "sciospec": (
        _baud(921_600),
        _ack(2.0, "each acknowledgement"),
        DeviceOption("first_channel", "int", 1, "", "board channel (1-based) wired to electrode 0"),
        DeviceOption("excitation_hz", "float", 10_000.0, "Hz", "excitation frequency", None, True),
        DeviceOption("frame_rate_hz", "float", 10.0, "Hz", "frames per second", None, True),
        DeviceOption("gain", "int", 1, "", "input gain", (1, 10, 100, 1000)),
        DeviceOption("adc_range_v", "int", 1, "V", "ADC range +-V", (1, 5, 10)),
    ),
    "cn0565": (
        DeviceOption(
            "uri",
            "str",
            "",
            "",
            "libiio context URI ('' : serial:<port>,230400,8n1 from the driver's port)",
        ),
        DeviceOption("excitation_hz", "float", 10_000.0, "Hz", "excitation frequency", None, True),
        NEGATIVE_INPUT_GAIN,
    ),
}
"""Profile name -> its options (every profile's ``baud`` where it has a serial port)."""

DEFAULT_PROFILE = "eit_skin"

OPENEIT_ELECTRODES = {8: "c", 16: "d", 32: "e"}
"""OpenEIT imaging modes: electrode count -> the mode letter the host writes."""

SCIOSPEC_MAX_CURRENT_A = 0.01
"""Largest excitation amplitude a Sciospec device accepts (sciopy: 10 mA)."""


@dataclass(frozen=True)
class DeviceSpec:
    """A layer's board: profile name and the options written in the patch.

    Attributes:
        profile: a key of :data:`PROFILES`.
        options: ``(name, value)`` pairs written in the file (others take their default).
    """

    profile: str = DEFAULT_PROFILE
    options: tuple[tuple[str, Any], ...] = ()

    def get(self, name: str) -> Any:
        """Option ``name``: the written value or the profile's default."""
        written = dict(self.options)
        if name in written:
            return written[name]
        for option in PROFILES[self.profile]:
            if option.name == name:
                return option.default
        raise KeyError(f"board profile {self.profile!r} has no option {name!r}")

    def offers(self, name: str) -> bool:
        """Whether the profile has option ``name``."""
        return any(option.name == name for option in PROFILES[self.profile])

    @property
    def negative_input_gain(self) -> float:
        """The minus input's gain over the plus input's (1 for a profile without the option)."""
        name = NEGATIVE_INPUT_GAIN.name
        return float(self.get(name)) if self.offers(name) else 1.0

    @property
    def baud(self) -> int:
        """Serial rate, bit/s (0 for a profile without a serial port)."""
        return int(self.get("baud")) if self.offers("baud") else 0


DEFAULT_DEVICE = DeviceSpec()
"""A layer without a ``device`` section: eit_skin's wire protocol at its default rate."""


def device_from_mapping(data: Mapping[str, Any], where: str, error) -> DeviceSpec:
    """Validate a ``device:`` mapping (keys already checked against the profile's options).

    ``error(key_path, reason)`` returns the exception to raise.
    """
    profile = data.get("profile", DEFAULT_PROFILE)
    options = []
    for option in PROFILES[profile]:
        if option.name not in data:
            continue
        value = data[option.name]
        key = f"{where}.{option.name}"
        options.append((option.name, _checked(option, value, key, error)))
    return DeviceSpec(profile, tuple(options))


def _checked(option: DeviceOption, value: Any, key: str, error) -> Any:
    kinds = {"int": (int,), "float": (int, float), "bool": (bool,), "str": (str,)}
    if option.kind != "bool" and isinstance(value, bool):
        raise error(key, f"expected {option.kind}, got {value!r}")
    if not isinstance(value, kinds[option.kind]):
        raise error(key, f"expected {option.kind}, got {value!r}")
    if option.kind == "float":
        value = float(value)
        if value != value or value in (float("inf"), float("-inf")):
            raise error(key, f"expected a finite number, got {value}")
    if option.positive and not value > 0:
        raise error(key, f"must be > 0, got {value}")
    if option.choices is not None and value not in option.choices:
        raise error(key, f"must be one of {', '.join(map(str, option.choices))}, got {value!r}")
    return value


def device_problem(
    device: DeviceSpec, spec: ProtocolSpec, protocol: Protocol, current_a: float
) -> tuple[str, str] | None:
    """Why ``device`` cannot read the layer's protocol: ``(key, reason)``, or None.

    The key is relative to the layer (``device.profile``, ``protocol.layout``, ...).
    """
    n = protocol.n_electrodes
    if device.negative_input_gain != 1.0 and not protocol.pair_drive:
        return "device.negative_input_gain", (
            "needs a pair drive: the inputs' ground is the injection's sink, which a current "
            "pattern does not have"
        )
    if device.profile == "openeit":
        if n not in OPENEIT_ELECTRODES:
            return "device.profile", f"OpenEIT images 8, 16 or 32 electrodes, the layer has {n}"
        if spec.drive != "opposite" or protocol.frame_size != n * (n - 4):
            return "protocol", (
                f"OpenEIT sends {n * (n - 4)} magnitudes of opposite drive per frame "
                f"(protocol: {{drive: opposite, measure: adjacent, values: magnitude}}); "
                f"this protocol ({protocol.name}) has {protocol.frame_size}"
            )
    if device.profile == "lines" and device.get("drop_zeros") and protocol.frame_index is None:
        return "device.drop_zeros", "needs protocol.layout: full (only a full layout has zeros)"
    if device.profile == "lines" and int(device.get("values")) not in (
        0,
        protocol.frame_size,
        protocol.n_measurements,
    ):
        return "device.values", (
            f"a line must carry the device frame ({protocol.frame_size} numbers) or the "
            f"protocol's {protocol.n_measurements} measurements, got {device.get('values')}"
        )
    if device.profile == "lines" and not set(device.get("separators")) - {"\r", "\n"}:
        return "device.separators", "needs at least one character other than CR and LF"
    if device.profile in ("sciospec", "cn0565") and protocol.frame_index is not None:
        return "protocol.layout", (
            f"{device.profile} boards send potentials or single measurements; the host forms "
            "the protocol's measurements (layout: compact)"
        )
    if device.profile == "sciospec":
        if not protocol.pair_drive:
            return "protocol.drive", "Sciospec drives one source and one sink per injection"
        first = int(device.get("first_channel"))
        if first < 1 or first + n - 1 > 64:
            return "device.first_channel", f"channels {first}..{first + n - 1} exceed 1..64"
        if current_a > SCIOSPEC_MAX_CURRENT_A:
            return "current", (
                f"{current_a:g} A exceeds the Sciospec maximum of {SCIOSPEC_MAX_CURRENT_A:g} A"
            )
    if device.profile == "cn0565":
        pair_patterns = ("adjacent", "skip", "opposite")
        if (
            n not in (8, 16, 32)
            or spec.drive not in pair_patterns
            or spec.measure not in pair_patterns
            or spec.order != "increasing"
            or spec.measure_driven
            or spec.sign != 1
        ):
            return "protocol", (
                "CN0565 (pyadi-iio) measures 8, 16 or 32 electrodes with a pair drive and "
                "pair measurements in increasing order, V(s+) - V(s-), driven electrodes left out"
            )
    return None


def options_table() -> str:
    """The profiles' options as the markdown table of docs/patch-schema.md (a test compares)."""
    rows = ["| profile | key | type | default | unit | meaning |", "|---|---|---|---|---|---|"]
    for profile, options in PROFILES.items():
        for option in options:
            kind = " \\| ".join(map(str, option.choices)) if option.choices else option.kind
            rows.append(
                f"| `{profile}` | `{option.name}` | {kind} | `{option.default!r}` | "
                f"{option.unit} | {option.description} |"
            )
    return "\n".join(rows)
