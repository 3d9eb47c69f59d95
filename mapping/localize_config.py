"""[localize]: `kosmap localize` (mapping/localize.py), Monte Carlo localization in a prior map or a blueprint.

Defaults follow ROS's AMCL (wiki.ros.org/amcl, its parameters) and Thrun, Burgard & Fox, *Probabilistic Robotics*
(2005), where they fit; where a narrow depth camera needs other values, the key says why.
"""

from __future__ import annotations

from dataclasses import dataclass

from kosmap.frontend.params import StageConfig, param


@dataclass
class LocalizeConfig(StageConfig):
    """[localize]: what is read of the log, the particle filter, recovery, and the scan-to-map refinement."""

    section = "localize"
    depth_rate: float = param(10.0, lo=0.0, doc="KOS steps per second localized (0 = every depth frame), as [build] depth_rate", unit="Hz")
    read_at_updates: bool = param(True, doc="with wheel odometry, a depth frame is read (FSPF+ and KOS, most of a run's time) only once the wheels moved update_min_d or turned update_min_a_deg since the last frame read, as AMCL takes a scan only then: the filter and the window's search use no other frames, and one in between would only repeat its neighbours' view; false = every frame at depth_rate")
    frame_max_period_s: float = param(0.5, lo=0.0, doc="... and at least this often (a standing robot still gets a pose; at most half max_gap_s, so that no gap is seen where none is)", unit="s")
    laser_rate: float = param(10.0, lo=0.0, doc="laser scans per second localized (0 = every scan)", unit="Hz")
    min_range: float = param(0.1, lo=0.0, doc="ignore returns nearer than this", unit="m")
    max_range: float = param(12.0, lo=0.0, lo_open=True, doc="ignore returns farther than this (AMCL laser_max_range; the KOS scan ends at [depth] max_depth)", unit="m")
    # the particle filter (AMCL: min_particles 100, max_particles 5000, kld_err 0.01, kld_z 0.99)
    min_particles: int = param(100, lo=1, doc="fewest particles (AMCL min_particles)")
    max_particles: int = param(5000, lo=1, doc="most particles while tracking or recovering (AMCL max_particles)")
    global_density: float = param(200.0, lo=0.0, lo_open=True, doc="particles per m² of free space to start global localization with: a 70° scan needs a particle within ~0.3 m and ~15° of the truth (1/(π·0.3²)·24 ≈ 85 per m², ×2)", unit="1/m²")
    global_max_particles: int = param(100000, lo=1, doc="cap on the global start (a 500 m² floor at global_density)")
    kld_err: float = param(0.01, lo=0.0, lo_open=True, doc="KLD-sampling's bound on the K–L divergence (AMCL kld_err)")
    kld_z: float = param(0.99, lo=0.5, hi=1.0, lo_open=True, doc="… holding with this probability (Fox 2003; AMCL kld_z)")
    bin_xy: float = param(0.5, lo=0.0, lo_open=True, doc="KLD histogram cell (AMCL's pf: 0.5 m)", unit="m")
    bin_yaw_deg: float = param(10.0, lo=0.0, lo_open=True, doc="KLD histogram heading bin (AMCL's pf: 10°)", unit="deg")
    update_min_d: float = param(0.2, lo=0.0, doc="translation between filter updates (AMCL update_min_d)", unit="m")
    update_min_a_deg: float = param(15.0, lo=0.0, doc="rotation between filter updates (AMCL update_min_a is 30°; a 70° view turned 30° sees half a new scene)", unit="deg")
    resample_interval: int = param(2, lo=1, doc="filter updates between resamplings (AMCL resample_interval)")
    odom_alpha: list = param([0.2, 0.2, 0.2, 0.2], doc="odometry motion model noise α1..α4 (AMCL odom_alpha1..4, diff model)")
    no_odom_period_s: float = param(0.5, lo=0.0, doc="without odometry, a filter update every this long (update_min_d at a walking pace; every scan would count one view many times)", unit="s")
    no_odom_sigma_xy: float = param(0.3, lo=0.0, lo_open=True, doc="random walk per second without odometry", unit="m")
    no_odom_sigma_yaw_deg: float = param(30.0, lo=0.0, lo_open=True, doc="… in heading", unit="deg")
    # the measurement model (AMCL likelihood_field: z_hit 0.95, z_rand 0.05, sigma_hit 0.2, max_beams 30)
    z_hit: float = param(0.7, lo=0.0, hi=1.0, lo_open=True, doc="likelihood field: weight of the Gaussian around the walls (AMCL laser_z_hit 0.95 is for a laser in a map of what it sees; a blueprint lacks the furniture that ends a third of a depth camera's returns)")
    z_rand: float = param(0.3, lo=0.0, hi=1.0, lo_open=True, doc="… of uniform noise: what furniture and people cost (AMCL laser_z_rand 0.05; see z_hit)")
    z_through: float = param(0.001, lo=0.0, hi=1.0, doc="… of a reading that passes through a wall by more than sigma_hit (a glass pane, an opening the map lacks); 0 = no ray check, the plain likelihood field")
    through_every: int = param(3, lo=1, doc="the through-wall check traces every this many of the max_beams end points (the tracing is most of a filter update's time)")
    sigma_hit: float = param(0.2, lo=0.0, lo_open=True, doc="… its standard deviation (AMCL laser_sigma_hit)", unit="m")
    sigma_search: float = param(0.5, lo=0.0, lo_open=True, doc="the through-wall tolerance (sigma_hit once found) while the pose is not found: a sparse global set's particle stands for poses ~0.3 m and ~15° around it, and with a 4 m reach 15° moves an end point ~1 m", unit="m")
    max_beams: int = param(30, lo=1, doc="end points per filter update, evenly spread over the scan (AMCL laser_max_beams)")
    effective_beams: float = param(8.0, lo=0.0, lo_open=True, doc="a scan's log-likelihood counts as this many independent end points at most: neighbouring returns off one wall are not independent (Probabilistic Robotics §6.4.1), and summed as if they were, one narrow scan collapses a global set onto a wrong room corner")
    min_points: int = param(10, lo=1, doc="a scan with fewer end points does not update the filter")
    # recovery (augmented MCL: AMCL recovery_alpha_slow/fast, 0.001 / 0.1 as its documentation suggests)
    alpha_slow: float = param(0.001, lo=0.0, hi=1.0, doc="long-term average of the measurement likelihood (AMCL recovery_alpha_slow)")
    alpha_fast: float = param(0.1, lo=0.0, hi=1.0, doc="short-term average (AMCL recovery_alpha_fast)")
    lost_ratio: float = param(0.2, lo=0.0, hi=1.0, doc="w_fast/w_slow below this: the pose is lost, and a global set is added to the particles")
    lost_through: float = param(0.1, lo=0.0, hi=1.0, doc="a refined pose whose readings pass more than through_tol through the map's walls this often (1 = never checked) ...")
    lost_through_s: float = param(2.0, lo=0.0, doc="... for this long is lost (kidnapped, or wrong): the search restarts as after a gap. At the right pose next to none do (the simulated room: ≤ 3 %); 1 s restarted the search on the noisier poses of a log without odometry", unit="s")
    through_tol: float = param(0.5, lo=0.0, doc="... with this tolerance, above a tracking error (a pose 0.2 m off reads 20 % of a narrow scan as through the wall at 0.2 m)", unit="m")
    max_gap_s: float = param(2.0, lo=0.0, lo_open=True, doc="scans this far apart in time: the robot may have been carried meanwhile, so a global set joins the particles and the pose must be found again", unit="s")
    # convergence
    converged_xy: float = param(0.25, lo=0.0, lo_open=True, doc="the spread of the particles' mode below which the pose counts as found", unit="m")
    converged_yaw_deg: float = param(10.0, lo=0.0, lo_open=True, doc="… and their heading spread", unit="deg")
    converged_share: float = param(0.6, lo=0.0, hi=1.0, lo_open=True, doc="… with at least this share of the weight in one mode (0.5 m, 30° around the pose)")
    converged_updates: int = param(10, lo=1, doc="… for this many filter updates in a row (~2 m of travel at update_min_d) before a pose is first claimed: one tight update can be a lucky wrong corner")
    # the global search of the last metres of scans that confirms a pose before it is claimed (mapping/localize_search.py)
    window_m: float = param(9.0, lo=0.0, lo_open=True, doc="the submap searched: this much travel of scans stitched by the odometry (two ranges of the depth camera's 4.5 m: a place is told from its look-alikes by what lies beyond one view)", unit="m")
    search_min_m: float = param(1.0, lo=0.0, doc="no search before the window holds this much travel (a single view fits too many places to be worth searching)", unit="m")
    search_every_m: float = param(1.0, lo=0.0, lo_open=True, doc="while no pose is held, the window is searched again after this much travel", unit="m")
    search_every_deg: float = param(35.0, lo=0.0, lo_open=True, doc="... or after this much turning (half the Kinect's 70° view: a turn in place shows a new view without travel)", unit="deg")
    check_m: float = param(3.0, lo=0.0, lo_open=True, doc="while a pose is held, the last this much travel of the window is searched over the map as a check: sure twice of another place, the robot was carried there (a window long enough to claim the room's pose from its first corner)", unit="m")
    check_every_m: float = param(1.0, lo=0.0, lo_open=True, doc="... every this much travel", unit="m")
    search_step: float = param(0.4, lo=0.0, lo_open=True, doc="the global search's coarse grid, its field blurred by as much (Olson 2009's low resolution)", unit="m")
    search_fine: float = param(0.1, lo=0.0, lo_open=True, doc="... its fine grid round each coarse maximum (two cells of a 5 cm map)", unit="m")
    search_keep: int = param(24, lo=2, doc="distinct places kept from the coarse search (each then searched finely)")
    search_apart: float = param(1.0, lo=0.0, lo_open=True, doc="places count as distinct this far apart ...", unit="m")
    search_apart_deg: float = param(20.0, lo=0.0, lo_open=True, doc="... or this far apart in heading", unit="deg")
    claim_p: float = param(0.99, lo=0.5, hi=1.0, doc="a pose is claimed when the search gives its place this posterior probability over every other place the submap fits (and its readings do not pass through walls, lost_through); the same bar for a laser's claim over every place its scan fits, and for moving a depth camera's track to a far mode")
    # tracking refined by the scan-to-map matcher (frontend/matcher.py gauss_newton against the map's field)
    refine: bool = param(True, doc="refine each pose by Gauss–Newton against the map, starting from the last refined pose moved by the odometry")
    match_sigma: float = param(0.05, lo=0.0, lo_open=True, doc="the matcher's field blur (one cell of a 5 cm map)", unit="m")
    refine_prior_xy: float = param(10.0, lo=0.0, doc="KOS: Gauss–Newton pull towards the predicted position, across the direction of travel (a tenth of the KOS profile's, backend/kosprofile.py: the map is fixed and right, a SLAM submap is not)", unit="1/m²")
    refine_prior_along: float = param(1.0, lo=0.0, doc="… along it: the weak pull a wide scan gets in every direction (refine_prior_laser). Along a corridor the narrow scan sees two parallel walls and only a door's edges fix the position, so whatever pulls along the path carries the wheels' scale error from one scan to the next (1 % is 1 cm per metre, added up until a crossing wall is in view): the simulated office's corridors 0.007-0.035 m RMSE at the simulator's 1 % and 0.036-0.064 m at 2 %, where a pull as hard as across (10) held the track up to 0.053 and 0.19 m off", unit="1/m²")
    refine_prior_yaw: float = param(10.0, lo=0.0, doc="… towards the predicted heading", unit="1/rad²")
    refine_search: float = param(0.3, lo=0.0, doc="where the refined track (re)starts at the filter's pose: a correlative search this far around it first (0 = none; the filter's mode is a few particle spacings wide)", unit="m")
    refine_search_deg: float = param(10.0, lo=0.0, doc="… and this far in heading", unit="deg")
    refine_prior_laser: float = param(1.0, lo=0.0, doc="the pull in every direction for a laser's wide scan, which fixes the pose by itself ([odometry] prior_weight's default)", unit="1/m², 1/rad²")
    refine_gate_sigmas: float = param(6.0, lo=0.0, lo_open=True, doc="the refined track is restarted at the filter's pose when they differ by more than this many of the filter's spreads (at least converged_xy)")
    seed: int = param(0, lo=0, doc="random seed of the particle filter (a run is repeatable)")
    mcap_particles: int = param(500, lo=0, doc="MCAP: at most this many particles per filter update (a subsample; 0 = none)")
