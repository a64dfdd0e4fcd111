"""``BodyModel``: a thin ``nn.Module`` over :mod:`arteq.body.lbs`, and :func:`load_body_model`.

One code path serves SMPL, SMPL-H (hands folded into the wrists) and the free bodies ``anny22`` (the
default) and ``anny_allages``.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import roma
import torch
from torch import nn

from arteq.body.lbs import shape_blend, skin
from arteq.body.skeleton import NUM_JOINTS, PARENTS
from arteq.body.smpl_io import LICENSE_HINT, BodyModelFileError, read_model_file, to_body22


class BodyOutput(NamedTuple):
    """Output of :meth:`BodyModel.forward` (batch dim absent when every input was unbatched)."""

    vertices: torch.Tensor  # [B, V, 3]
    joints: torch.Tensor  # [B, 22, 3] posed
    global_rotmats: torch.Tensor  # [B, 22, 3, 3]
    rest_joints: torch.Tensor  # [B, 22, 3]


def _pose_to_rotmats(pose: torch.Tensor) -> tuple[torch.Tensor, bool]:
    """Accept ``[B,22,3,3]``, ``[B,22,3]``, ``[B,66]`` or their unbatched forms; return ``[B,22,3,3]``."""
    K = NUM_JOINTS
    shape = tuple(pose.shape)
    if shape[-2:] == (3, 3) and len(shape) in (3, 4) and shape[-3] == K:
        return (pose if len(shape) == 4 else pose[None]), len(shape) == 3
    if shape[-1] == 3 and len(shape) in (2, 3) and shape[-2] == K:
        rot = roma.rotvec_to_rotmat(pose.reshape(-1, 3)).reshape(-1, K, 3, 3)
        return rot, len(shape) == 2
    if shape[-1] == 3 * K and len(shape) in (1, 2):
        rot = roma.rotvec_to_rotmat(pose.reshape(-1, 3)).reshape(-1, K, 3, 3)
        return rot, len(shape) == 1
    raise ValueError(
        f"BodyModel: `pose` must be [B,{K},3,3] rotation matrices, [B,{K},3] or [B,{3 * K}] axis-angle "
        f"(batch dim optional), got {list(shape)}"
    )


class BodyModel(nn.Module):
    """SMPL-format body model with 22 joints; all model data in non-persistent buffers.

    Buffers: ``v_template [V,3]``, ``shapedirs [V,3,num_betas]``, ``posedirs [P,V*3]`` (``P = 0``: no pose
    correctives), ``J_regressor [22,V]``, ``lbs_weights [V,22]``, ``faces [F,3]`` long, ``part_labels [V]``
    long (argmax of the skinning weights), ``parents [22]`` long.
    """

    def __init__(
        self,
        v_template: torch.Tensor | np.ndarray,
        shapedirs: torch.Tensor | np.ndarray,
        posedirs: torch.Tensor | np.ndarray | None,
        J_regressor: torch.Tensor | np.ndarray,
        lbs_weights: torch.Tensor | np.ndarray,
        faces: torch.Tensor | np.ndarray,
        num_betas: int | None = None,
        name: str = "body",
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__()

        def t(x, dt=dtype):
            return torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x).to(dt)

        v = t(v_template)
        V = v.shape[0]
        sd = t(shapedirs)
        if num_betas is None:
            num_betas = sd.shape[-1]
        if num_betas > sd.shape[-1]:
            raise ValueError(f"BodyModel '{name}': asked for {num_betas} betas, the model has {sd.shape[-1]}")
        w = t(lbs_weights)
        if w.shape != (V, NUM_JOINTS):
            raise ValueError(f"BodyModel '{name}': lbs_weights must be [{V}, 22], got {list(w.shape)}")
        pd = t(posedirs) if posedirs is not None else torch.zeros(0, V * 3, dtype=dtype)
        # Not persistent: a body is rebuilt from its file or config, never saved in (or loaded from) a
        # state dict, so checkpoints of modules holding one carry no (licensed) body data.
        buffers = {
            "v_template": v,
            "shapedirs": sd[..., :num_betas].contiguous(),
            "posedirs": pd,
            "J_regressor": t(J_regressor),
            "lbs_weights": w,
            "faces": t(faces, torch.long),
            "part_labels": w.argmax(dim=1),
            "parents": torch.tensor(PARENTS, dtype=torch.long),
        }
        for key, value in buffers.items():
            self.register_buffer(key, value, persistent=False)
        self.num_betas = int(num_betas)
        self.num_vertices = int(V)
        self.name = name

    @classmethod
    def from_npz(cls, path: str | Path, num_betas: int | None = None, name: str | None = None) -> BodyModel:
        """Load an SMPL-format ``.npz`` (official SMPL/SMPL-H npz or a cached anny22 file)."""
        return cls.from_file(path, num_betas=num_betas, name=name)

    @classmethod
    def from_file(cls, path: str | Path, num_betas: int | None = None, name: str | None = None) -> BodyModel:
        """Load an SMPL-format ``.npz`` or ``.pkl`` (SMPL 24 joints / SMPL-H 52 folded to 22)."""
        path = Path(path).expanduser()
        arr = to_body22(read_model_file(path), source=str(path))
        return cls(
            arr["v_template"],
            arr["shapedirs"],
            arr["posedirs"] if arr["posedirs"].shape[0] else None,
            arr["J_regressor"],
            arr["weights"],
            arr["faces"],
            num_betas=num_betas,
            name=name or path.stem,
        )

    def forward(
        self,
        betas: torch.Tensor | None = None,
        pose: torch.Tensor | None = None,
        transl: torch.Tensor | None = None,
    ) -> BodyOutput:
        """Pose and shape the body.

        Args:
            betas: ``[B, nb]`` with ``nb <= num_betas`` (missing columns are zero), or ``None`` (zeros).
            pose: ``[B,22,3,3]`` local rotmats, ``[B,22,3]`` / ``[B,66]`` axis-angle, or ``None``
                (rest pose).
            transl: ``[B, 3]`` or ``None``.
            Any argument may drop its batch dim; if all given ones do, outputs drop it too. Batch size 1
            broadcasts.
        Returns:
            :class:`BodyOutput` (vertices ``[B,V,3]``, joints ``[B,22,3]``, global_rotmats
            ``[B,22,3,3]``, rest_joints ``[B,22,3]``).
        """
        dtype, device = self.v_template.dtype, self.v_template.device
        unbatched = []
        rot = None
        if pose is not None:
            rot, ub = _pose_to_rotmats(pose.to(dtype))
            unbatched.append(ub)
        if betas is not None:
            if betas.dim() not in (1, 2):
                raise ValueError(f"BodyModel: `betas` must be [B, nb] or [nb], got {list(betas.shape)}")
            unbatched.append(betas.dim() == 1)
            betas = betas.to(dtype)[None] if betas.dim() == 1 else betas.to(dtype)
            if betas.shape[1] > self.num_betas:
                raise ValueError(
                    f"BodyModel '{self.name}': got {betas.shape[1]} betas, the model has {self.num_betas}"
                )
        if transl is not None:
            if transl.shape[-1] != 3 or transl.dim() not in (1, 2):
                raise ValueError(f"BodyModel: `transl` must be [B, 3] or [3], got {list(transl.shape)}")
            unbatched.append(transl.dim() == 1)
            transl = transl.to(dtype)[None] if transl.dim() == 1 else transl.to(dtype)
        sizes = {x.shape[0] for x in (rot, betas, transl) if x is not None} - {1}
        if len(sizes) > 1:
            raise ValueError(f"BodyModel: inconsistent batch sizes {sorted(sizes)} in betas/pose/transl")
        B = sizes.pop() if sizes else 1
        if rot is None:
            rot = torch.eye(3, dtype=dtype, device=device).expand(B, NUM_JOINTS, 3, 3)
        if betas is None:
            betas = torch.zeros(B, self.num_betas, dtype=dtype, device=device)
        rot = rot.expand(B, -1, -1, -1)
        betas = betas.expand(B, -1)
        if transl is not None:
            transl = transl.expand(B, -1)
        v_shaped, rest_joints = self.shape(betas)
        posedirs = self.posedirs if self.posedirs.shape[0] else None
        out = (*skin(v_shaped, rest_joints, rot, self.lbs_weights, PARENTS, posedirs, transl), rest_joints)
        if unbatched and all(unbatched):
            out = tuple(o[0] for o in out)
        return BodyOutput(*out)

    def shape(self, betas: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Shaped rest vertices ``[B, V, 3]`` and rest joints ``[B, 22, 3]`` for ``betas [B, nb]``
        (linear shape blendshapes; a procedural body may override this, the skinning stays shared)."""
        return shape_blend(betas, self.v_template, self.shapedirs, self.J_regressor)

    def extra_repr(self) -> str:
        return (
            f"name={self.name!r}, num_vertices={self.num_vertices}, num_faces={self.faces.shape[0]}, "
            f"num_betas={self.num_betas}, pose_correctives={self.posedirs.shape[0] > 0}"
        )


def _find_smpl_file(model_path: Path, name: str, gender: str) -> Path:
    if model_path.is_file():
        return model_path
    if not model_path.exists():
        raise BodyModelFileError(f"{name} model file not found: '{model_path}'. {LICENSE_HINT}")
    g = {"neutral": "neutral", "male": "male", "female": "female"}[gender]
    cands = sorted(
        p
        for p in model_path.rglob("*")
        if p.suffix.lower() in (".npz", ".pkl")
        and g in p.name.lower()
        and not (g == "male" and "female" in p.name.lower())
    )
    cands += sorted(p for p in (model_path / g).glob("model.npz"))  # SMPL-H layout: <dir>/<gender>/model.npz
    if not cands:
        raise BodyModelFileError(
            f"no {gender} {name} model file (.pkl/.npz with '{gender}' in its name) under '{model_path}'. "
            + LICENSE_HINT
        )
    return cands[0]


#: Free bodies built from the ``anny`` package: name -> the module whose ``spec()`` defines it.
ANNY_BODIES = {"anny22": "arteq.body.anny22", "anny_allages": "arteq.body.anny_allages"}
#: Every body name :func:`load_body_model` knows.
BODY_NAMES = (*ANNY_BODIES, "smpl", "smplh", "smpl-h")


def load_body_model(
    name: str = "anny22",
    model_path: str | None = None,
    num_betas: int | None = None,
    gender: str = "neutral",
) -> BodyModel:
    """Load a body model by name; Hydra target of ``conf/body_model/*.yaml``.

    Args:
        name: ``"anny22"`` (free default, adults) or ``"anny_allages"`` (free, ages 2-90 and extreme
            builds), built from ``anny`` into the cache on first use if ``model_path`` is None; or
            ``"smpl"`` / ``"smplh"`` (licensed files: ``model_path`` required).
        model_path: a model file, or for SMPL a folder searched for a file with ``gender`` in its name.
        num_betas: shape coefficients kept (error if the file has fewer); None: the body's default
            (10; anny_allages: :data:`arteq.body.anny_allages.DEFAULT_NUM_BETAS`).
        gender: ``"neutral"``, ``"male"`` or ``"female"`` (SMPL only; the Anny bodies are gender-neutral:
            gender is one of their shape dimensions).
    """
    if gender not in ("neutral", "male", "female"):
        raise ValueError(f"load_body_model: gender must be neutral/male/female, got {gender!r}")
    name = name.lower()
    if name in ANNY_BODIES:
        import importlib

        from arteq.body.anny_rig import ensure_body

        module_name = ANNY_BODIES[name]
        spec = importlib.import_module(module_name).spec()
        if model_path is None:
            path = ensure_body(spec)
        else:
            path = Path(model_path).expanduser()
            if not path.is_file():
                raise BodyModelFileError(
                    f"{name} model file not found: '{path}'. Build it with `python -m {module_name} "
                    f"--out {path}` or drop `body_model.model_path` to use the cached default."
                )
        nb = spec.default_num_betas if num_betas is None else num_betas
        return BodyModel.from_npz(path, num_betas=nb, name=name)
    if num_betas is None:
        num_betas = 10
    if name in ("smpl", "smplh", "smpl-h"):
        if model_path is None or str(model_path) in ("", "???"):
            raise BodyModelFileError(f"body model '{name}' needs `body_model.model_path`. {LICENSE_HINT}")
        path = _find_smpl_file(Path(model_path).expanduser(), name, gender)
        return BodyModel.from_file(path, num_betas=num_betas, name=name)
    raise ValueError(
        f"load_body_model: unknown body model {name!r} (expected one of {', '.join(map(repr, BODY_NAMES))})"
    )
