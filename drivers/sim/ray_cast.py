"""The renderer's per-pixel ray cast, compiled (numba): from each pixel's ray to where it
samples the scene's texture atlas.

`atlas_maps` does in one pass over the image what `drivers.sim.scene.EyeRenderer` describes:
the nearest exit plane of the room, the slab entry into each box within the image window its
edges project to, then the atlas coordinates of the face hit. Written with numpy the same
arithmetic takes some forty whole-image passes and as many temporaries a frame, which made it
the largest part of a simulated frame's cost; here it is one loop with no temporaries. Every
quantity is float32 and computed in the same order as the numpy formulation, so the maps are
the same numbers. `cache=True` keeps the compiled code beside this file, so only the first
process pays the compile time.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _maximum(a: np.float32, b: np.float32) -> np.float32:
    """`np.maximum` of two numbers: NaN if either is."""
    if a != a or a >= b:
        return a
    return b


@njit(cache=True, nogil=True, inline="always")
def _minimum(a: np.float32, b: np.float32) -> np.float32:
    """`np.minimum` of two numbers: NaN if either is."""
    if a != a or a <= b:
        return a
    return b


@njit(cache=True, nogil=True, error_model="numpy")
def atlas_maps(directions: np.ndarray, eye: np.ndarray, lo: np.ndarray, hi: np.ndarray, eye_in_box: np.ndarray,
               windows: np.ndarray, face_normal: np.ndarray, su: np.ndarray, sv: np.ndarray, offset_x: np.ndarray,
               offset_y: np.ndarray, outside: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> None:
    """Fill `map_x`, `map_y` (H, W) float32 with the atlas coordinates each pixel samples.

    `directions` (H, W, 3): each pixel's ray in the world frame; `eye` (3,): the optical centre;
    `lo`, `hi` (boxes, 3): the boxes' corners, the room first; `eye_in_box` (boxes, 3): the
    centre as each box sees it (a moved box is met where the ray from the centre less its move
    meets it unmoved); `windows` (boxes, 4): rows [r0, r1) and columns [c0, c1) a box may cover
    (empty: none; the room's row is not read). Per face id (6 a box): `face_normal` its normal
    axis, atlas x = (t d_u) su + offset_x and y = (t d_v) sv + offset_y, the eye's position
    folded into the offsets. `outside` (H, W) bool: pixels beyond the lens's image circle,
    sent off the atlas (the border colour)."""
    height, width = map_x.shape
    one = np.float32(1.0)
    zero = np.float32(0.0)
    boxes = lo.shape[0]
    room_lo = lo[0] - eye
    room_hi = hi[0] - eye
    for r in range(height):
        for c in range(width):
            d0, d1, d2 = directions[r, c, 0], directions[r, c, 1], directions[r, c, 2]
            i0, i1, i2 = one / d0, one / d1, one / d2
            # The room, seen from inside: the nearest of the three exit planes.
            t0 = _maximum(room_lo[0] * i0, room_hi[0] * i0)
            t1 = _maximum(room_lo[1] * i1, room_hi[1] * i1)
            t2 = _maximum(room_lo[2] * i2, room_hi[2] * i2)
            best = _minimum(t0, t1)
            if t2 < best:
                face = 5 if d2 > zero else 4
            elif t1 < t0:
                face = 3 if d1 > zero else 2
            else:
                face = 1 if d0 > zero else 0
            best = _minimum(best, t2)
            for b in range(1, boxes):
                if r < windows[b, 0] or r >= windows[b, 1] or c < windows[b, 2] or c >= windows[b, 3]:
                    continue
                o0, o1, o2 = eye_in_box[b, 0], eye_in_box[b, 1], eye_in_box[b, 2]
                a0, e0 = (lo[b, 0] - o0) * i0, (hi[b, 0] - o0) * i0
                a1, e1 = (lo[b, 1] - o1) * i1, (hi[b, 1] - o1) * i1
                a2, e2 = (lo[b, 2] - o2) * i2, (hi[b, 2] - o2) * i2
                min0, min1, min2 = _minimum(a0, e0), _minimum(a1, e1), _minimum(a2, e2)
                near01 = _maximum(min0, min1)
                t_near = _maximum(near01, min2)
                t_far = _minimum(_minimum(_maximum(a0, e0), _maximum(a1, e1)), _maximum(a2, e2))
                if t_near <= t_far and t_near > zero and t_near < best:
                    # The entry face: the axis whose slab is entered last; its lo face if the ray runs +.
                    if min2 >= near01:
                        face = 6 * b + 4 + (1 if d2 < zero else 0)
                    elif min1 >= min0:
                        face = 6 * b + 2 + (1 if d1 < zero else 0)
                    else:
                        face = 6 * b + (1 if d0 < zero else 0)
                    best = t_near
            normal = face_normal[face]
            d_u = d1 if normal == 0 else d0
            d_v = d1 if normal == 2 else d2
            x = best * d_u
            x *= su[face]
            x += offset_x[face]
            y = best * d_v
            y *= sv[face]
            y += offset_y[face]
            map_x[r, c] = np.float32(-100.0) if outside[r, c] else x
            map_y[r, c] = y
