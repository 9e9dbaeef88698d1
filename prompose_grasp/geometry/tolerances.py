"""Named tolerances, in one place, so a reader knows what "close enough" means everywhere.

Each one says why it has its value. Tests use these names rather than bare literals where the meaning matches.
"""

#: A matrix is accepted as a rotation when |R^T R - I| and |det R - 1| stay below this. float64 products of a
#: few rotations stay near 1e-15; 1e-6 also admits rotations that went through float32 storage (eps 1.2e-7).
ROTATION_ATOL = 1e-6

#: Below this angle [rad] the series expansions of exp/log replace the closed forms, whose terms divide by
#: theta^2 or theta^3 and lose all precision (theta^2 ~ 1e-16 is float64's resolution around 1).
SMALL_ANGLE_RAD = 1e-6

#: Intrinsics: focal lengths must be positive and principal points finite; depth readings at or below this
#: distance [m] are treated as missing (no RGB-D sensor reports geometry closer than 1 mm).
MIN_VALID_DEPTH_M = 1e-3

#: The median of a depth image's readings must lie in this range [m] (`pointcloud.check_depth_units`).
#: Consumer RGB-D cameras measure from ~0.1 m (RealSense D405: 7 cm; D435: ~0.2 m; Azure Kinect: 0.25 m) to
#: at most ~10 m (D435 at its limit; Kinect v2 4.5 m, Azure Kinect 5.5 m). A whole image's median outside
#: 5 cm - 10 m is not a scene any of them sees: it is a unit mistake, most often millimetres passed as metres
#: (a table at 0.8 m reads 800).
DEPTH_MEDIAN_RANGE_M = (0.05, 10.0)

#: A point counts as inside a box when it is outside by at most this fraction of the larger box's longest
#: side. Edge/face crossing points are computed with a few float64 roundings (relative error ~1e-16 each);
#: 1e-9 keeps corners that lie exactly on a face while adding at most ~1e-9 relative error to an
#: intersection volume.
BOX_INSIDE_RTOL = 1e-9

#: An intersection polytope whose smallest principal spread is below this fraction of the box scale is flat
#: (touching faces, edges or corners): its volume is 0 and Qhull, which would fail on it, is not called.
BOX_FLAT_RTOL = 1e-9

#: Default tolerances of `Pose9D.allclose`: rotation angle [rad] and translation / size [m]. Poses that went
#: through a few float64 conversions (matrix, NOCS sRT, a transform and its inverse) agree to ~1e-15; 1e-9 rad
#: and 1 nm say "the same pose up to rounding", far below anything a sensor can resolve.
POSE_ALLCLOSE_RAD = 1e-9
POSE_ALLCLOSE_M = 1e-9

#: Slack of the separating-axis test [m] (and of its near-parallel edge axes [-]): boxes that touch count as
#: overlapping, whatever the last bit of the float64 projections says (they are ~1e-16 relative off).
SAT_EPS = 1e-12
