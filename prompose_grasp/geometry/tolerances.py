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
