"""``POST /perceive``: one RGB-D frame, perceived by the server as the testbed's robot perceives.

``runtime/frame.py`` does the work (segmentation, one grasp-network pass, the crops' embeddings,
the size and cavity cues, the finger checks, the hand's approach); this module is the request's
shape and its decoding, so that ``serve/app.py`` only wires the endpoint. Decoding and the two
network passes run in a worker thread under the server's encoder lock (torch's thread setting is
process-global); the choice runs on the event loop, where the grounders live.
"""

from __future__ import annotations

import base64
import binascii
from typing import TYPE_CHECKING, Annotated

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

if TYPE_CHECKING:
    from ..grasp.geometry import CameraIntrinsics
    from ..perception.workspace import Workspace

#: strict: ``true`` for a focal length became 1 pixel (a 9 m grasp opening), and "615" went through
#: as a number where ``craft perceive`` refuses it
_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)
MAX_FOCAL_PX = 1e5  # pixels: far beyond any camera; keeps a typo from becoming an overflow


class CameraIn(BaseModel):
    """The colour image's pinhole model, and optionally the camera's pose."""

    model_config = _STRICT

    fx: Annotated[float, Field(gt=0.0, le=MAX_FOCAL_PX, description="Focal length, pixels.")]
    fy: Annotated[float, Field(gt=0.0, le=MAX_FOCAL_PX, description="Focal length, pixels.")]
    cx: Annotated[float, Field(ge=-MAX_FOCAL_PX, le=MAX_FOCAL_PX, description="Principal point x, pixels.")]
    cy: Annotated[float, Field(ge=-MAX_FOCAL_PX, le=MAX_FOCAL_PX, description="Principal point y, pixels.")]
    cam_to_world: list[list[float]] | None = Field(None, description=(
        "4 x 4, camera frame (OpenCV: x right, y down, z forward) to a world frame with z up; left "
        "out, heights are measured from the table plane fitted in the frame."))

    @field_validator("cam_to_world")
    @classmethod
    def _four_by_four(cls, value: list[list[float]] | None) -> list[list[float]] | None:
        if value is not None and (len(value) != 4 or any(len(row) != 4 for row in value)):
            raise ValueError("cam_to_world must be a 4 x 4 matrix (rows of 4 numbers)")
        if value is not None and any(abs(v) > 1e6 for row in value for v in row):
            raise ValueError("cam_to_world holds a number beyond 1e6: not a pose in metres")
        return value

    def intrinsics(self, width: int, height: int) -> CameraIntrinsics:
        from ..grasp.geometry import CameraIntrinsics

        return CameraIntrinsics(width, height, self.fx, self.fy, self.cx, self.cy)


_METRES = Field(ge=-1e6, le=1e6, description="Metres, in cam_to_world's world frame.")


class WorkspaceIn(BaseModel):
    """The x-y box of the table the robot picks from, and optionally a ceiling
    (``perception/workspace.py``): depth outside it is read as no reading. Needs the camera's
    ``cam_to_world``."""

    model_config = _STRICT

    x_min: Annotated[float, _METRES]
    x_max: Annotated[float, _METRES]
    y_min: Annotated[float, _METRES]
    y_max: Annotated[float, _METRES]
    z_max: Annotated[float, Field(ge=-1e6, le=1e6, description=(
        "Optional ceiling (world z, metres): points above it are no object to pick (the arm's links)."))] | None = None

    @model_validator(mode="after")
    def _ordered(self) -> WorkspaceIn:
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError("each minimum must lie below its maximum (x_min < x_max, y_min < y_max)")
        return self

    def workspace(self) -> Workspace:
        from ..perception.workspace import Workspace

        return Workspace(self.x_min, self.x_max, self.y_min, self.y_max, self.z_max)


def decode_base64(text: str) -> bytes | None:
    """The bytes of strict base64, or None when it is not base64."""
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        return None
