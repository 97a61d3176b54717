"""PX4 flight modes the mock knows, the mode groups and the offboard-loss failsafe actions."""

from __future__ import annotations

from enum import Enum


class Mode(Enum):
    """PX4 flight modes the mock knows: value = (main_mode, sub_mode, base_mode flags)."""

    MANUAL = (1, 0, 64 | 16)
    ALTCTL = (2, 0, 64 | 16)
    POSCTL = (3, 0, 64 | 16)
    AUTO_TAKEOFF = (4, 2, 4 | 8 | 16)
    AUTO_LOITER = (4, 3, 4 | 8 | 16)
    AUTO_MISSION = (4, 4, 4 | 8 | 16)
    AUTO_RTL = (4, 5, 4 | 8 | 16)
    AUTO_LAND = (4, 6, 4 | 8 | 16)
    ACRO = (5, 0, 64)
    OFFBOARD = (6, 0, 16)
    STABILIZED = (7, 0, 64 | 16)

    @property
    def custom_mode(self) -> int:
        main, sub, _ = self.value
        return (main << 16) | (sub << 24)

    @property
    def label(self) -> str:
        return _MODE_LABELS[self]

    @classmethod
    def from_custom(cls, main: int, sub: int) -> Mode | None:
        for m in cls:
            if m.value[0] == main and (m.value[1] == sub or (main != 4 and sub == 0)):
                return m
        if main == 4 and sub == 1:  # AUTO.READY: PX4 treats it as Hold on a multicopter
            return cls.AUTO_LOITER
        return None


_MODE_LABELS = {
    Mode.MANUAL: "Manual",
    Mode.ALTCTL: "Altitude",
    Mode.POSCTL: "Position",
    Mode.AUTO_TAKEOFF: "Takeoff",
    Mode.AUTO_LOITER: "Hold",
    Mode.AUTO_MISSION: "Mission",
    Mode.AUTO_RTL: "Return",
    Mode.AUTO_LAND: "Land",
    Mode.ACRO: "Acro",
    Mode.OFFBOARD: "Offboard",
    Mode.STABILIZED: "Stabilized",
}
MANUAL_MODES = frozenset({Mode.MANUAL, Mode.ALTCTL, Mode.POSCTL, Mode.ACRO, Mode.STABILIZED})
AUTO_MODES = frozenset(
    {Mode.AUTO_TAKEOFF, Mode.AUTO_LOITER, Mode.AUTO_MISSION, Mode.AUTO_RTL, Mode.AUTO_LAND}
)
# COM_OBL_RC_ACT -> failsafe mode (None = disarm)
OFFBOARD_LOSS_ACTIONS: dict[int, Mode | None] = {
    0: Mode.POSCTL,
    1: Mode.ALTCTL,
    2: Mode.MANUAL,
    3: Mode.AUTO_RTL,
    4: Mode.AUTO_LAND,
    5: Mode.AUTO_LOITER,
    6: None,
    7: None,
}
