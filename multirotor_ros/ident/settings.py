"""The thresholds of log preparation and fitting, in one documented value.

:func:`multirotor_ros.ident.samples.load_samples` takes a :class:`FitSettings` (the defaults when none is
given) and the :class:`~multirotor_ros.ident.samples.FlightSamples` it returns carry it into every fit of
that log (:mod:`multirotor_ros.ident.fit`), so that a log is prepared and judged with one set of numbers.
The online identifier (:class:`multirotor_ros.ident.rls.OnlineSettings`) judges its refits by the same
``identifiable_relative_std``.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FitSettings:
    """How a log is cut into usable samples and when a fitted parameter is believed."""

    # [-] A time step longer than this many median steps is a gap: nothing is derived or integrated across
    # it. Above 2 so that one dropped sample (a step of 2) still counts as continuous; the filters and the
    # motor-lag discretisation tolerate that much jitter.
    gap_factor: float = 2.5
    # [samples] Fewer usable samples than this and a log is refused: below it even k_f alone has a standard
    # deviation that says nothing, and the Newey-West bandwidth (about n/4 at most) has no room.
    min_usable_samples: int = 50
    # [m] Rotors closer to the ground than this may have the landing gear touching: the ground's reaction
    # is in no model, so those samples are not fitted. 2 cm is above the height noise of motion capture.
    min_rotor_height_m: float = 0.02
    # [-] k_f sum(omega^2) / (m |a + g|) outside this range: the log is not of this airframe (or its rotor
    # speeds are not in rad/s). A factor of 2 either way is far beyond any plausible k_f or mass error.
    mismatch_ratio: tuple[float, float] = (0.5, 2.0)
    # [-] The same ratio outside this range but within mismatch_ratio: a warning that k_f, the mass or the
    # motor map is off by more than the 20-25 % a configured airframe is expected to be within.
    plausible_ratio: tuple[float, float] = (0.8, 1.25)
    # [s] An actuator fault's onset is searched only where this much usable flight follows it: a shorter
    # stretch cannot tell a weak rotor from a gust (about ten periods of the attitude loop).
    min_fault_duration_s: float = 0.3
    # [-] A parameter is identifiable when its std is below this share of max(|value - neutral|, scale):
    # at 0.5 the data tell a value of the size that matters from none at two standard deviations.
    identifiable_relative_std: float = 0.5
    # [-] A parameter found not identifiable whose column correlates at least this much with another's is
    # reported as "nearly collinear with" it rather than as lacking excitation.
    collinear_correlation: float = 0.95
    # [-] Columns correlated at least this much are one column (the log gives only their combination):
    # one of the pair is held at once, whatever its std, since noise in the inputs makes each std
    # meaningless. Close to 1 so that a merely strong correlation is left to the std test.
    exactly_collinear: float = 0.9995
    # [designs] Regression designs kept per log: a search revisits grid values and cross-validation folds
    # share designs; 48 holds two scalar grids of 16 values with their refinements, at a few MB each.
    design_cache_size: int = 48

    def __post_init__(self) -> None:
        for name, (low, high) in (
            ("mismatch_ratio", self.mismatch_ratio),
            ("plausible_ratio", self.plausible_ratio),
        ):
            if not 0 < low <= 1 <= high:
                raise ValueError(f"{name} must hold 1 between two positive bounds, got ({low}, {high})")
        if not self.gap_factor > 1:
            raise ValueError(f"gap_factor must be > 1, got {self.gap_factor}")
        if self.min_usable_samples < 1 or self.design_cache_size < 1:
            raise ValueError("min_usable_samples and design_cache_size must be >= 1")
        if not 0 < self.collinear_correlation <= self.exactly_collinear <= 1:
            raise ValueError("need 0 < collinear_correlation <= exactly_collinear <= 1")
        if not self.identifiable_relative_std > 0:
            raise ValueError(f"identifiable_relative_std must be > 0, got {self.identifiable_relative_std}")
