"""SDL2's GameController API through pysdl2 (the optional `gamepad` extra), headless.

Only the game controller subsystem (and the joystick and event subsystems it needs) is started: no
video, no window (SDL_VIDEODRIVER=dummy in case anything asks). SDL counts its subsystem references,
so the adapter and anyone else in the process (a test's virtual pad) each hold one.

The state is read whole, not from SDL's event queue: the queue is one per process, so two pads (or an
adapter and a test) reading it would take each other's events. `SDL_GameControllerUpdate` refreshes
the state and notices pads plugged in or out; events are switched off so the queue does not fill.
"""

from __future__ import annotations

import ctypes
import os
import threading
import warnings
from types import ModuleType
from typing import Any

from servo_app.inputs.gamepad.mapping import (
    AXIS_FULL_SCALE,
    AXIS_NAMES,
    BUTTON_NAMES,
    TRIGGERS,
    PadState,
    normalize_axes,
)

_load_lock = threading.Lock()
# The pads open through SdlPad in this process (SDL instance ID -> the input reading it): each pad is
# read by one input only, so a second gamepad input takes the next pad instead of the first one again.
_claimed: dict[int, str] = {}
_claim_lock = threading.Lock()


def load_sdl() -> ModuleType:
    """The pysdl2 module, its library loaded; RuntimeError saying what to install otherwise."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    with _load_lock:
        try:
            with warnings.catch_warnings():
                # pysdl2 announces the bundled library on import; that is the intended setup, not news.
                warnings.filterwarnings("ignore", message="Using SDL2 binaries", category=UserWarning)
                import sdl2  # optional dependency: pip install 'servo_app[gamepad]'
        except (ImportError, RuntimeError) as exc:  # RuntimeError: pysdl2 present, no libSDL2 found
            raise RuntimeError("the gamepad adapter needs pysdl2 and pysdl2-dll "
                               f"(pip install 'servo_app[gamepad]'): {exc}") from exc
    return sdl2


def _error(sdl: ModuleType) -> str:
    return (sdl.SDL_GetError() or b"").decode(errors="replace")


class SdlControllers:
    """One reference on SDL's game controller subsystem; `close` gives it back."""

    def __init__(self) -> None:
        sdl = self.sdl = load_sdl()
        # Without this SDL takes SIGINT and SIGTERM for itself (as SDL_QUIT events nobody reads),
        # and the service would no longer stop on Ctrl-C or from systemd.
        sdl.SDL_SetHint(sdl.SDL_HINT_NO_SIGNAL_HANDLERS, b"1")
        # A service has no window, so it never has the focus SDL otherwise waits for.
        sdl.SDL_SetHint(sdl.SDL_HINT_JOYSTICK_ALLOW_BACKGROUND_EVENTS, b"1")
        if sdl.SDL_InitSubSystem(sdl.SDL_INIT_GAMECONTROLLER) != 0:
            raise OSError(f"SDL cannot start its game controller subsystem: {_error(sdl)}")
        sdl.SDL_GameControllerEventState(sdl.SDL_IGNORE)
        sdl.SDL_JoystickEventState(sdl.SDL_IGNORE)
        self._open = True

    def close(self) -> None:
        if self._open:
            self._open = False
            self.sdl.SDL_QuitSubSystem(self.sdl.SDL_INIT_GAMECONTROLLER)

    def joysticks(self) -> list[tuple[int, str, bool]]:
        """Every joystick SDL sees now: (device index, name, whether SDL has a controller mapping)."""
        sdl = self.sdl
        sdl.SDL_GameControllerUpdate()  # notices pads plugged in since the last look
        out = []
        for i in range(sdl.SDL_NumJoysticks()):
            name = (sdl.SDL_JoystickNameForIndex(i) or b"?").decode(errors="replace")
            out.append((i, name, bool(sdl.SDL_IsGameController(i))))
        return out


class NoPad(OSError):
    """No game controller matches: nothing plugged in, nothing SDL has a mapping for, or every pad that
    would do is already read by another input (`taken`: (pad name, input name))."""

    def __init__(self, message: str, seen: list[tuple[int, str, bool]],
                 taken: list[tuple[str, str]] | None = None) -> None:
        super().__init__(message)
        self.seen = seen
        self.taken = taken or []


class SdlPad:
    """One open game controller, read whole on each call."""

    def __init__(self, controllers: SdlControllers, match: str | None = None, owner: str = "") -> None:
        self.sdl = sdl = controllers.sdl
        self.instance_id: int | None = None
        with _claim_lock:
            seen = controllers.joysticks()
            taken: list[tuple[str, str]] = []
            index = None
            for i, name, mapped in seen:
                if not mapped or (match is not None and match.lower() not in name.lower()):
                    continue
                holder = _claimed.get(sdl.SDL_JoystickGetDeviceInstanceID(i))
                if holder is None:
                    index = i
                    break
                taken.append((name, holder))
            if index is None:
                named = f" named like {match!r}" if match else ""
                raise NoPad(f"no {'free ' if taken else ''}game controller{named}", seen, taken)
            self._pad = sdl.SDL_GameControllerOpen(index)
            if not self._pad:
                raise OSError(f"SDL cannot open game controller {index}: {_error(sdl)}")
            self.instance_id = sdl.SDL_JoystickInstanceID(sdl.SDL_GameControllerGetJoystick(self._pad))
            _claimed[self.instance_id] = owner or "?"
        self.name = (sdl.SDL_GameControllerName(self._pad) or b"?").decode(errors="replace")
        self.has_rumble = bool(sdl.SDL_GameControllerHasRumble(self._pad))
        self._axes = range(len(AXIS_NAMES))
        self._buttons = range(len(BUTTON_NAMES))

    def read(self) -> PadState:
        """The pad's state now; ConnectionResetError once it is unplugged."""
        sdl, pad = self.sdl, self._pad
        sdl.SDL_GameControllerUpdate()
        if not sdl.SDL_GameControllerGetAttached(pad):
            raise ConnectionResetError(f"game controller {self.name!r} was unplugged")
        axes = normalize_axes([sdl.SDL_GameControllerGetAxis(pad, a) for a in self._axes])
        buttons = 0
        for b in self._buttons:
            if sdl.SDL_GameControllerGetButton(pad, b):
                buttons |= 1 << b
        return PadState(axes, buttons)

    def rumble(self, strength: float, duration_ms: int) -> bool:
        """Both motors at `strength` (0..1) for `duration_ms`; False if the pad cannot."""
        level = round(max(0.0, min(1.0, strength)) * 0xFFFF)
        return self.has_rumble and self.sdl.SDL_GameControllerRumble(self._pad, level, level, duration_ms) == 0

    def close(self) -> None:
        pad, self._pad = self._pad, None
        if pad:
            self.sdl.SDL_GameControllerClose(pad)
        if self.instance_id is not None:
            with _claim_lock:
                _claimed.pop(self.instance_id, None)


_RumbleFn = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_uint16, ctypes.c_uint16)


class VirtualPad:
    """SDL's virtual joystick in the game controller layout, so SDL maps it as it maps an Xbox pad: a real
    SDL device (for tests and for trying the adapter without a pad), set with `axis` and `button`.
    With `rumble`, the rumbles asked of it are kept in `rumbles` as (low, high) motor levels."""

    def __init__(self, name: str = "servo_app virtual pad", *, rumble: bool = True) -> None:
        self.controllers = SdlControllers()
        sdl = self.sdl = self.controllers.sdl
        self.rumbles: list[tuple[int, int]] = []
        desc = sdl.SDL_VirtualJoystickDesc()
        desc.version = sdl.SDL_VIRTUAL_JOYSTICK_DESC_VERSION
        desc.type = sdl.SDL_JOYSTICK_TYPE_GAMECONTROLLER
        desc.naxes = len(AXIS_NAMES)
        desc.nbuttons = len(BUTTON_NAMES)
        desc.name = name.encode()
        if rumble:
            # Kept on self: SDL calls it for as long as the device lives.
            self._on_rumble: Any = _RumbleFn(self._rumbled)
            desc.Rumble = self._on_rumble
        self.index = sdl.SDL_JoystickAttachVirtualEx(ctypes.byref(desc))
        if self.index < 0:
            error = _error(sdl)
            self.controllers.close()
            raise OSError(f"SDL cannot attach a virtual joystick: {error}")
        self._joystick = sdl.SDL_JoystickOpen(self.index)
        self.instance_id = sdl.SDL_JoystickInstanceID(self._joystick)  # device indices shift as pads come and go
        self.attached = True

    def _rumbled(self, _user: object, low: int, high: int) -> int:
        self.rumbles.append((low, high))
        return 0

    def axis(self, name: str, value: float) -> None:
        """Sticks -1..1 (up and left negative, as SDL reads them); triggers 0..1."""
        a = AXIS_NAMES.index(name)
        if a in TRIGGERS:  # the raw axis spans -32768 (released) to 32767; SDL's mapping halves it
            raw = round(-32768 + max(0.0, min(1.0, value)) * 65535)
        else:
            raw = round(max(-1.0, min(1.0, value)) * AXIS_FULL_SCALE)
        if self.sdl.SDL_JoystickSetVirtualAxis(self._joystick, a, raw) != 0:
            raise OSError(f"SDL cannot set {name}: {_error(self.sdl)}")

    def button(self, name: str, held: bool) -> None:
        if self.sdl.SDL_JoystickSetVirtualButton(self._joystick, BUTTON_NAMES.index(name), int(held)) != 0:
            raise OSError(f"SDL cannot set {name}: {_error(self.sdl)}")

    def detach(self) -> None:
        """Unplug it."""
        if self.attached:
            self.attached = False
            sdl = self.sdl
            index = next(i for i in range(sdl.SDL_NumJoysticks())
                         if sdl.SDL_JoystickGetDeviceInstanceID(i) == self.instance_id)
            sdl.SDL_JoystickClose(self._joystick)
            if sdl.SDL_JoystickDetachVirtual(index) != 0:
                raise OSError(f"SDL cannot detach the virtual joystick: {_error(sdl)}")

    def close(self) -> None:
        self.detach()
        self.controllers.close()
