"""Janome JR3000 / JC-3 / JS3 as a robot backend: servo_app listens, the robot's point job connects."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from servo_app.backends import AlarmInfo, ProcessOptions, RobotBackend, Target
from servo_app.janome.alarms import alarm_for_code
from servo_app.janome.motion import StreamSpeeds, stream_speeds
from servo_app.janome.profile import JanomeProfile, available_janome_profiles, load_janome_profile
from servo_app.janome.runner import DEFAULT_PORT, JanomeConfig, JanomeProcess
from servo_app.janome.view import janome_view
from servo_app.messages import Event


class JanomeBackend(RobotBackend):
    name = "janome"
    default_port = DEFAULT_PORT
    default_model = "jr3000"
    listens = True  # the robot is the TCP client (manual 21.1)

    @classmethod
    def models(cls) -> list[str]:
        return available_janome_profiles()

    @classmethod
    def resolve_model(cls, model: str | None) -> str:
        # The service's model option defaults to a FANUC arm: any name Janome does not know means
        # "the default Janome model" (a path to a profile TOML is taken as given).
        if model and (model in cls.models() or model.endswith(".toml")):
            return model
        return cls.default_model

    def load_profile(self, model: str) -> JanomeProfile:
        return load_janome_profile(model)

    def make_process(self, target: Target, options: ProcessOptions, on_event: Callable[[Event], None],
                     on_exit: Callable[[str], None]) -> JanomeProcess:
        return JanomeProcess(JanomeConfig(host=target.host, port=target.port, model=self.model,
                                          log_dir=options.log_dir, input_slot=options.input_slot),
                             on_event=on_event, on_exit=on_exit)

    def start_simulator(self, target: Target, sim_options: dict[str, Any], realtime_priority: int | None) -> Any:
        from servo_app.sim.process import JanomeSimulatorProcess

        return JanomeSimulatorProcess(server=(target.host, target.port), model=self.model).start()

    def axes(self) -> list[dict[str, Any]]:
        return self.robot_view([0.0] * 4)["axes"]  # type: ignore[no-any-return]

    def robot_view(self, q: list[float]) -> dict[str, Any]:
        # The axes' speeds a jog may ask (the console's jog slider is a share of them), not the profile's.
        return janome_view(self.profile, q, [float(v) for v in self.speeds()[0].vel])

    def target_bounds(self) -> list[tuple[float, float]] | None:
        # The work envelope's bounding box (JanomeMotion.check_target refuses outside the envelope).
        return list(zip(self.profile.axis_min, self.profile.axis_max, strict=True))

    def speeds(self) -> tuple[StreamSpeeds, JanomeConfig]:
        """The speeds the servo process commands: it is made with JanomeConfig's defaults (make_process)."""
        cfg = JanomeConfig()
        step_s = cfg.step_s or self.profile.step_s
        return stream_speeds(self.profile, step_s, cfg.speed_fraction), cfg

    def limits(self, state: dict[str, Any], options: ProcessOptions) -> dict[str, Any]:
        p = self.profile
        sp, cfg = self.speeds()
        return {
            "model": p.name,
            "backend": self.name,
            "axes": ["X", "Y", "Z", "R"],
            "source": "profile (configured), speeds held to the link's step",
            "axis_min": list(p.axis_min),
            "axis_max": list(p.axis_max),
            # What a jog may ask and a move runs at: the profile's speeds are not, where the link's
            # step is tighter (800 mm/s in the JR3000's profile, 10 mm per 0.1 s step streamed).
            "speed": [float(v) for v in sp.vel],
            "speed_source": list(sp.vel_source),
            "accel": list(p.accel),
            "cp_speed_mm_s": float(sp.cp_speed),
            "cp_speed_source": sp.cp_source,
            "profile_speed": list(p.speed),
            "profile_cp_speed_mm_s": p.cp_speed,
            "speed_fraction": cfg.speed_fraction,
            "step_s": cfg.step_s or p.step_s,
            "max_step_mm": p.max_step_mm,
            "max_step_deg": p.max_step_deg,
        }

    def alarm(self, code: str) -> AlarmInfo | None:
        spec = alarm_for_code(code)
        return None if spec is None else AlarmInfo(code, spec.cause, spec.remedy)
