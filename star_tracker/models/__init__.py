# SPDX-License-Identifier: Apache-2.0
"""
Shared models every stage uses.

The camera (pixel <-> ray), the star catalog (and its validated on-disk cache), rotations,
and attitude estimation from vector pairs.
"""
