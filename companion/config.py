"""Typed configuration of the companion (the ``[companion]`` tables of a config file).

Defaults are the paper's parameters; ``configs/default.toml`` mirrors them (a test checks).
Each section belongs to the module named in its docstring.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, PositiveInt, model_validator

from colcommon.configio import Section, build, read_toml, section, with_experiment_task
from companion.errors import ConfigError

KNOWN_TOP_LEVEL = {"sitl", "companion", "experiment"}


class LinkConfig(Section):
    """companion.link: how to reach the vehicle."""

    connection: str = "udpin:0.0.0.0:14540"
    source_system: int = Field(1, ge=1, le=255)
    source_component: int = Field(191, ge=1, le=255, description="MAV_COMP_ID_ONBOARD_COMPUTER")
    heartbeat_timeout_s: float = Field(3.0, gt=0)
    link_lost_s: float = Field(1.5, gt=0, description="no telemetry this long -> link lost")
    command_timeout_s: float = Field(1.0, gt=0)
    command_retries: int = Field(3, ge=0)
    baud: int = Field(57600, gt=0, description="serial devices without a ',BAUD' suffix")
    heartbeat_period_s: float = Field(1.0, gt=0, description="our own HEARTBEAT (onboard controller)")
    telemetry_rate_hz: float = Field(50.0, ge=0, description="ATTITUDE, LOCAL_POSITION_NED; 0 = leave as is")
    status_rate_hz: float = Field(10.0, ge=0, description="EXTENDED_SYS_STATE (touchdown detection); 0 = leave as is")
    request_rates_on_connect: bool = True
    stop_unread_streams: bool = Field(
        False, description="on connect, also stop the vehicle's streams the companion never reads (lockstep "
        "experiments: about 40 % fewer messages to encode, send, parse and log per frame; a ground station on "
        "the same vehicle loses them too)")
    frame_marker: Literal["SYSTEM_TIME", "LOCAL_POSITION_NED", "ATTITUDE"] = Field(
        "SYSTEM_TIME", description="message whose arrival ends a frame (SITL lockstep: SYSTEM_TIME)"
    )
    setpoint_max_speed_m_s: float = Field(10.0, gt=0, description="the link refuses faster setpoints")
    setpoint_max_yaw_rate_rad_s: float = Field(3.0, gt=0)
    setpoint_max_distance_m: float = Field(1000.0, gt=0, description="position setpoints from origin")
    takeoff_max_alt_m: float = Field(120.0, gt=0)
    signing_key_file: str = Field(
        "", description="MAVLink 2 signing key (64 hex digits); sign everything, trust only signed messages; empty = off"
    )


class CommandsConfig(Section):
    """companion.commands: joystick -> body-frame velocity setpoint."""

    v_xy_max_m_s: float = Field(2.0, gt=0)
    v_z_max_m_s: float = Field(1.0, gt=0)
    yaw_rate_max_rad_s: float = Field(1.0, gt=0)
    deadband: float = Field(0.05, ge=0, lt=1)
    expo: float = Field(0.0, ge=0, le=1)


class SessionConfig(Section):
    """companion.session: the episode loop."""

    control_rate_hz: float = Field(10.5, gt=0)
    clock: Literal["wall", "vehicle"] = Field(
        "wall", description="real time: steps paced by the wall clock, or by the vehicle's time_boot_ms (an "
        "autopilot's SITL run faster than real time: PX4_SIM_SPEED_FACTOR, ArduCopter --speedup)")
    max_steps: int = Field(500, gt=0)
    episodes: int = Field(4, gt=0)
    output_dir: str = "runs"
    seed: int = Field(0, ge=0, description="episode i starts from seed + i")
    link_patience_s: float = Field(10.0, gt=0, description="link lost this long -> give the episode up")
    # Episode starts on a vehicle without a simulator (fly there, then hand over).
    pad_ned_m: tuple[float, float, float] = Field((0.0, 0.0, -1.5), description="where the pad is, local NED")
    policy_pad_ned_m: tuple[float, float, float] | None = Field(
        None, description="where the pad was, from home, in the world the policy learned in (our SITL's experiments: "
        "[0, 0, -1.5], on the ground vehicle's roof); the position the policy and the person see is shifted so that "
        "the pad sits there, for a policy flown where the pad stands elsewhere (a real autopilot's ground: "
        "pad_ned_m [0, 0, 0]); none: the position from home as measured (docs/camera.md, \"The policy's frame\")")
    start_height_above_pad_m: float = Field(8.0, gt=0)
    start_xy_range_m: float = Field(3.0, ge=0)
    start_tolerance_m: float = Field(0.3, gt=0, description="at the start point within this -> hand over")
    takeoff_alt_m: float = Field(2.5, gt=0)
    arm_timeout_s: float = Field(
        60.0, ge=0, description="a vehicle refusing to arm (still booting) is retried this long"
    )
    end_of_run: Literal["land", "hold"] = Field(
        "land", description="after the last episode, Ctrl-C or an episode error: land or hold"
    )
    autopilot_sim_disturbance: bool = Field(
        False, description="a real autopilot's SITL (no simulator of ours): set its simulator's wind and turbulence "
        "from [sitl.disturbance] at each episode start (ArduCopter SIM_WIND_*; PX4 SIH has no wind), docs/link.md")
    touchdown_by_truth_contact: bool = Field(
        False, description="a real autopilot's SITL that sends its truth, the rendered pad driving (no surface there): "
        "the first truth sample within truth_contact_m of the ground where the vehicle stood disarmed is a touchdown, "
        "and the vehicle is then disarmed, forced (only a SITL has truth); companion/control/truth_contact.py")
    truth_contact_m: float = Field(0.05, gt=0, le=1, description="touchdown_by_truth_contact: this close to the ground")
    sih_mass_scale: float = Field(
        1.0, gt=0, le=5, description="PX4 SIH: SIH_MASS set to this x the value it had (a heavier vehicle than trained on)")
    sih_drag_scale: float = Field(
        1.0, gt=0, le=10, description="PX4 SIH: SIH_KDV (translational drag) set to this x the value it had")


class SafetyConfig(Section):
    """companion.safety: geofence around the start of the session."""

    fence_radius_m: float = Field(30.0, gt=0)
    fence_min_alt_m: float = Field(-1.0, description="below home; -1 allows touching down on the ground")
    fence_max_alt_m: float = Field(25.0, gt=0)
    max_accel_xy_m_s2: float = Field(
        0.0, ge=0, description="setpoint rate limit, forward/right; 0 disables"
    )
    max_accel_z_m_s2: float = Field(0.0, ge=0, description="setpoint rate limit, down; 0 disables")
    max_yaw_accel_rad_s2: float = Field(
        0.0, ge=0, description="setpoint rate limit, yaw rate; 0 disables"
    )


class PerceptionConfig(Section):
    """companion.perception: camera source and pad detector (see docs/camera.md)."""

    camera: str = Field(
        "auto", description='"auto" (the vehicle\'s MAVLink camera), "render" (our renderer driven by the vehicle\'s telemetry), colf://host:port, a device index, a file or a URL; '
        '"none": no camera, the pad is never visible (a test mode)'
    )
    open_timeout_s: float = Field(3.0, gt=0, description="a source that gives no frame this long fails at start")
    render_rate_hz: float = Field(30.0, gt=0, le=100, description='camera "render": frames per second rendered from telemetry')
    frame_timeout_s: float = Field(0.2, ge=0, description="how long to wait for the frame of a control step")
    hue_min: int = Field(135, ge=0, le=179, description="OpenCV hue (0-179) range of the pad's magenta")
    hue_max: int = Field(170, ge=0, le=179)
    saturation_min: int = Field(110, ge=0, le=255, description="about halfway between pad and roof")
    value_min: int = Field(35, ge=0, le=255, description="darker pixels carry no reliable hue")
    min_area_px: float = Field(12.0, gt=0, description="smaller magenta blobs are noise")
    min_solidity: float = Field(0.85, gt=0, le=1, description="blob area / convex hull area: the pad is convex")


class LearnerConfig(Section):
    """companion.learner: the paper's Update-Policy procedure (companion/learning/learner.py)."""

    hidden: tuple[PositiveInt, ...] = Field((130, 72, 40), min_length=1)
    init_std: float = Field(0.1, gt=0, description="std of the normal weight init; biases start at 0")
    learning_rate: float = Field(1e-4, gt=0)
    batch_size: int = Field(64, gt=0)
    loss_threshold: float = Field(0.005, gt=0)
    max_updates: int = Field(2000, gt=0, description="updates per round; a round restarts on new samples")
    torch_threads: int = Field(1, ge=1)
    seed: int = 0
    mode: Literal["thread", "process", "budgeted"] = Field(
        "thread",
        description="thread: live, as fast as the CPU allows; process: the same in a child "
        "process (needs a dataset file); budgeted: reproducible",
    )
    updates_per_step: int = Field(50, ge=1, description="budgeted mode: updates per control step")
    between_episode_updates: int = Field(
        40_000, ge=0,
        description="budgeted mode: updates after each episode, before its checkpoint, as a live "
        "learner trains while the vehicle is repositioned (the paper's round cap still applies)",
    )
    publish_every_updates: int = Field(
        8, ge=1, description="publish a snapshot at least this often (and after any new data)"
    )
    thread_nice: int = Field(10, ge=0, le=19, description="learner thread's or process's OS niceness")
    control_guard_s: float = Field(
        0.003, ge=0, le=0.05, description="learner thread steps aside this long before a control tick"
    )
    gil_switch_interval_s: float = Field(
        0.001, gt=0, le=0.1, description="while the learner thread runs: bounds control's GIL wait"
    )
    ensemble_members: int = Field(
        1, ge=1, le=32,
        description="K copies of the network, each on its own minibatches, flying their mean action; "
        "1 = the paper's single network; asking for help ([companion.ask]) needs >= 2 (5 is usual)",
    )
    # Switches beyond the paper (docs/learner.md, "Learner switches"); each off by default.
    mirror_augment: bool = Field(
        False, description="every minibatch also holds each sample's left/right mirror image (east, roll, "
        "yaw, their rates, the pad's image column and the roll and yaw sticks negated): twice the rows"
    )
    intervention_weight: float = Field(
        1.0, gt=0, le=1000, description="weight of an intervention sample in the loss (a demonstration's "
        "is 1; the loss is the minibatch's weighted mean); 1 = the paper's MSE"
    )
    takeover_steps: int = Field(
        0, ge=0, description="the first this many samples of each take-over weigh takeover_weight; 0 = none"
    )
    takeover_weight: float = Field(
        1.0, gt=0, le=1000, description="weight of a take-over's first takeover_steps samples (instead of "
        "intervention_weight)"
    )
    demo_noise_std: float = Field(
        0.0, ge=0, le=1, description="DART: while the person demonstrates, the vehicle flies their sticks plus "
        "Gaussian noise of this std (stick units), seeded by the learner's seed and the episode; the sample "
        "keeps the person's command; 0 = none (the paper)"
    )
    huber_delta: float = Field(
        0.0, ge=0, le=2, description="Huber loss: each action error's gradient capped at this many stick units "
        "(a lapse's stale command pulls no harder than this); the stopping rule still reads the MSE; 0 = the "
        "paper's MSE"
    )
    holdout_stop: bool = Field(
        False, description="hold out holdout_share of the samples (never trained on); between episodes "
        "(budgeted mode) train until their loss stops improving, at most between_episode_updates, and "
        "publish the weights' moving average at its best check"
    )
    holdout_share: float = Field(0.1, gt=0, lt=1, description="holdout_stop: share of the samples held out")
    holdout_block_samples: int = Field(
        10, ge=1, description="holdout_stop: samples are held out in blocks of this many consecutive ones"
    )
    holdout_check_every_updates: int = Field(100, ge=1, description="holdout_stop: updates between checks")
    holdout_patience_checks: int = Field(
        20, ge=1, description="holdout_stop: stop after this many checks without a better held-out loss"
    )
    weight_average_decay: float = Field(
        0.999, ge=0, lt=1, description="holdout_stop: the published weights' exponential moving average, "
        "per update; 0 = the last weights"
    )


class PilotConfig(Section):
    """companion.pilot: the scripted expert, the synthetic intervention rule, human inputs."""

    # What the expert knows about the scene, as a person would (pad size, camera view).
    pad_radius_m: float = Field(0.5, gt=0, description="radius of the landing pad's disc")
    camera_hfov_deg: float = Field(90.0, gt=10, lt=170, description="horizontal field of view")
    # The expert's gains, in stick units.
    xy_gain_per_m: float = Field(0.4, ge=0, description="stick per metre of offset from the pad")
    xy_damping_per_m_s: float = Field(0.25, ge=0, description="stick per m/s of ground speed")
    xy_trim_per_m_s: float = Field(
        0.15, ge=0, description="stick per metre-second of lasting offset (a pilot's trim)"
    )
    xy_trim_max: float = Field(0.3, ge=0, le=1, description="largest trim, in stick units")
    xy_stick_max: float = Field(0.6, gt=0, le=1)
    descent_stick_fast: float = Field(0.8, ge=0, le=1, description="descent when high")
    descent_stick_slow: float = Field(0.3, ge=0, le=1, description="descent near touchdown")
    slow_height_m: float = Field(2.0, gt=0, description="below this height, descend slowly")
    descent_cone: float = Field(
        0.25, ge=0, description="descend at full rate while offset <= cone * height"
    )
    centre_tolerance_m: float = Field(0.2, ge=0, description="offset that always counts as centred")
    commit_height_m: float = Field(
        1.0, ge=0, description="below this height, centred: stop steering by the image, set down"
    )
    commit_off_centre_m: float = Field(
        0.3, ge=0, description="centred this well below commit_height_m -> set down level"
    )
    set_down_by_picture: bool = Field(
        False, description="once committed, a partial pad whose centre is in the picture still steers (off: the "
                           "remembered position, judged by the vehicle's own position estimate)"
    )
    lead_moving_pad: bool = Field(
        False, description="follow the pad's own motion, judged from the picture (companion/inputs/pad_motion.py): "
                           "hold the pad's speed, damp the speed relative to it, and set down where it has driven to "
                           "(off: as over a still pad)"
    )
    lead_stick_per_m_s: float = Field(
        0.5, ge=0, le=2, description="with lead_moving_pad, the stick held per m/s of the pad's speed: the pilot's "
                                     "feel for the vehicle, 1 / companion.commands.v_xy_max_m_s"
    )
    judge_drift_by_picture: bool = Field(
        False, description="judge the drift the ground-speed reading does not show from the pad sliding across the "
                           "picture (companion/inputs/picture_drift.py): damp the speed relative to the pad and lean "
                           "against the drift with lead_stick_per_m_s (off: the reading is believed; real autopilots: "
                           "results/real-autopilots/RENDER.md)"
    )
    drift_time_constant_s: float = Field(
        0.5, gt=0, le=10, description="with judge_drift_by_picture, the drift's smoothing at 1 m above the pad "
                                      "(times the height above 1 m)"
    )
    search_climb_stick: float = Field(0.3, ge=0, le=1, description="climb while the pad is lost")
    lost_hold_s: float = Field(
        0.5, ge=0, description="pad lost shorter than this -> keep the last command (a blink)"
    )
    # Intervention rule of a synthetic operator (take over ... let go).
    takeover_edge_fraction: float = Field(
        0.8, gt=0, le=1, description="pad this far towards the image edge (0 centre, 1 edge)"
    )
    takeover_descent_m_s: float = Field(1.5, gt=0, description="descending faster than this")
    takeover_low_descent_m_s: float = Field(
        0.7, gt=0, description="descending faster than this below takeover_low_height_m (a hard landing)"
    )
    takeover_predicted_miss_m: float = Field(
        0.45, ge=0, description="touchdown projected this far from the pad's centre -> take over; 0 disables"
    )
    anticipation_s: float = Field(
        3.0, ge=0, description="a touchdown expected within this long is projected from the current velocity"
    )
    takeover_low_height_m: float = Field(2.0, ge=0, description="'low' for the off-centre test")
    takeover_off_centre_m: float = Field(0.6, gt=0, description="off-centre when low")
    takeover_touchdown_speed_m_s: float = Field(
        0.4, gt=0, description="ground speed that is too fast once committed to touchdown"
    )
    takeover_stall_s: float = Field(
        6.0, ge=0, description="no progress down for this long -> take over; 0 disables"
    )
    takeover_stall_descent_m: float = Field(0.5, gt=0, description="what counts as progress")
    release_descent_m: float = Field(
        0.5, ge=0, description="descended this much since taking over before letting go"
    )
    release_edge_fraction: float = Field(0.5, gt=0, le=1)
    release_off_centre_m: float = Field(0.3, gt=0)
    release_hold_s: float = Field(1.0, ge=0, description="back on track this long -> let go")
    # A ground station's joystick (MAVLink MANUAL_CONTROL).
    manual_override_button: int = Field(0, ge=0, le=31, description="bit of buttons/buttons2")
    manual_timeout_s: float = Field(0.5, gt=0, description="older message -> neutral, no override")
    manual_throttle_range: tuple[int, int] = Field(
        (0, 1000), description="z from the ground station for throttle -1 and +1 (QGC: 0..1000)"
    )
    # A local gamepad (pygame); SDL axis numbers and signs in roll, pitch, yaw, throttle order.
    gamepad_index: int = Field(0, ge=0)
    gamepad_axes: tuple[int, int, int, int] = (3, 4, 0, 1)
    gamepad_invert: tuple[bool, bool, bool, bool] = (False, True, False, True)
    gamepad_trigger_axis: int = Field(5, ge=-1, description="analog trigger axis; -1 = none")
    gamepad_trigger_button: int = Field(-1, ge=-1, description="button as trigger; -1 = none")
    gamepad_trigger_threshold: float = Field(0.5, gt=-1, lt=1)

    @model_validator(mode="after")
    def _consistent(self) -> PilotConfig:
        lo, hi = self.manual_throttle_range
        if lo == hi:
            raise ValueError("manual_throttle_range needs two different values, e.g. [0, 1000]")
        if self.release_off_centre_m > self.takeover_off_centre_m:
            raise ValueError("release_off_centre_m must not exceed takeover_off_centre_m")
        if self.release_edge_fraction > self.takeover_edge_fraction:
            raise ValueError("release_edge_fraction must not exceed takeover_edge_fraction")
        if self.judge_drift_by_picture and not self.set_down_by_picture:
            raise ValueError("judge_drift_by_picture needs set_down_by_picture: the drift is judged from the pad in "
                             "the picture, also while setting down")
        if self.judge_drift_by_picture and self.lead_moving_pad:
            raise ValueError("judge_drift_by_picture and lead_moving_pad both judge the motion relative to the pad; "
                             "turn one of them off")
        return self


class AskConfig(Section):
    """companion.ask: the policy holds and asks the person for help when its ensemble disagrees
    (companion/control/ask.py, docs/ask-for-help.md)."""

    enabled: bool = Field(False, description="ask in intervention episodes (needs learner.ensemble_members >= 2)")
    target_rate: float = Field(
        0.02, gt=0, lt=1,
        description="threshold = the (1 - target_rate) quantile of the ensemble's disagreement on the "
        "dataset's states, recalibrated at every episode start",
    )
    min_samples: int = Field(64, ge=1, description="no requests before the dataset holds this many samples")
    answer_timeout_s: float = Field(15.0, gt=0, description="nobody took over this long after a request")
    on_timeout: Literal["land", "hold"] = Field("land", description="then: land where it is, or keep holding")
    rearm_s: float = Field(2.0, ge=0, description="after the person hands back, fly this long before asking again")
    synthetic_response_s: float = Field(
        1.0, ge=0, le=30, description="a synthetic participant starts looking this long after a request")


class LandingConfig(Section):
    """companion.landing: touchdowns that the vehicle's own land detector recognises.

    Real PX4 registers ground contact only while the commanded descent is at least
    1.1 x LNDMC_Z_VEL_MAX; a slow final descent sits on the ground, armed, until the episode
    times out. With ``touchdown_assist`` the companion sees that the vehicle stopped on a surface
    while asked down, and asks down at what the detector needs (docs/link.md, "Touchdown")."""

    touchdown_assist: bool = Field(True, description="raise a too-slow descent once the vehicle stands on a surface")
    assist_after_s: float = Field(1.0, gt=0, le=10, description="asked down, came down less than half of it over this long -> standing on a surface")
    stall_speed_m_s: float = Field(0.1, gt=0, le=1, description="vertical speed below this counts as not moving")
    assist_height_m: float = Field(
        0.7, ge=0, le=10, description="only this close above the pad's height above home, or lower")
    descent_margin: float = Field(1.2, ge=1, le=3, description="ask this many times the detector's minimum descent")
    min_descent_m_s: float = Field(
        0.0, ge=0, le=2, description="the detector's minimum descent; 0 = from the vehicle (PX4: 1.1 x LNDMC_Z_VEL_MAX)")
    evidence_touchdown_s: float = Field(
        3.0, gt=0, le=30, description="a vehicle that reports no landed state: standing this long with the assist on is a touchdown")


MIN_TELEMETRY_PER_STEP = 2.0
"""ATTITUDE and LOCAL_POSITION_NED are asked for at least this many times per control step."""


class CompanionConfig(Section):
    link: LinkConfig = LinkConfig()
    commands: CommandsConfig = CommandsConfig()
    session: SessionConfig = SessionConfig()
    safety: SafetyConfig = SafetyConfig()
    perception: PerceptionConfig = PerceptionConfig()
    learner: LearnerConfig = LearnerConfig()
    pilot: PilotConfig = PilotConfig()
    ask: AskConfig = AskConfig()
    landing: LandingConfig = LandingConfig()

    @model_validator(mode="after")
    def _ask_needs_ensemble(self) -> CompanionConfig:
        if self.ask.enabled and self.learner.ensemble_members < 2:
            raise ValueError("[companion.ask] enabled needs an ensemble to measure disagreement: "
                             "set [companion.learner] ensemble_members to 2 or more (5 is usual)")
        return self

    @model_validator(mode="after")
    def _telemetry_outpaces_control(self) -> CompanionConfig:
        """A step needs telemetry newer than the last step's (companion/control/freshness.py): at
        less than twice the control rate, steps would hold on stale telemetry by design."""
        rate, control = self.link.telemetry_rate_hz, self.session.control_rate_hz
        if 0 < rate < MIN_TELEMETRY_PER_STEP * control:
            raise ValueError(f"[companion.link] telemetry_rate_hz = {rate:g} is below {MIN_TELEMETRY_PER_STEP:g} x the "
                             f"control rate ({control:g} Hz): steps would hold on stale telemetry; ask for at least "
                             f"{MIN_TELEMETRY_PER_STEP * control:g} Hz (50 is usual), or 0 to leave the vehicle's rates")
        return self


def load_companion_config(path: str | Path | None = None) -> CompanionConfig:
    """The ``[companion]`` part of a config file, or the embedded defaults when ``path`` is None."""
    if path is None:
        return CompanionConfig()
    data = read_toml(path)
    unknown = set(data) - KNOWN_TOP_LEVEL
    if unknown:
        raise ConfigError(
            f"{path}: unknown top-level table(s) {sorted(unknown)}; expected some of "
            f"{sorted(KNOWN_TOP_LEVEL)}"
        )
    return build(CompanionConfig, with_experiment_task(data, section(data, "companion"), EXPERIMENT_TASK), f"[companion] in {path}")


EXPERIMENT_TASK: dict[tuple[str, str], object] = {("landing", "touchdown_assist"): False}
"""Settings added after the experiments were designed, with the values that fly their task as it
was run: an experiment file (one with an ``[experiment]`` table) that does not name them gets
these, so its committed results stay what its trials give. Our SITL keeps the old land detector
for such files too (sitl/config.py), and with it no assist is needed."""

