"""What an evaluation looks at: the regular sampling and a fixed set of transitions, and the
scores of h on it (shared by fit and sweep; RunDir.write_evaluation records them)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from smspace.lake.dataset import Dataset
from smspace.lake.normalise import normalisers
from smspace.metrics import spatial_scores

N_PREDICTIONS = 16  # predicted vs true s_t1 kept per evaluation, for viewers and reports


@dataclass
class EvalData:
    """What every evaluation looks at: the regular sampling and a fixed set of transitions."""

    m_regular: torch.Tensor  # normalised with the dataset's motor statistics
    p_regular: np.ndarray
    m_t: torch.Tensor
    s_t: torch.Tensor
    m_t1: torch.Tensor
    s_t1: torch.Tensor

    @classmethod
    def load(cls, ds: Dataset, n: int, device: torch.device) -> EvalData:
        m_norm, s_norm = normalisers(ds.manifest)
        m_reg, p_reg = ds.regular_sampling()
        head = ds.read_all(n)

        def col(name: str, norm) -> torch.Tensor:
            return torch.from_numpy(norm(getattr(head, name))).to(device)

        return cls(
            torch.from_numpy(m_norm(m_reg)).to(device),
            p_reg.astype(np.float64),
            col("m_t", m_norm),
            col("s_t", s_norm),
            col("m_t1", m_norm),
            col("s_t1", s_norm),
        )


def scores_row(h: np.ndarray, p: np.ndarray, eval_loss: float) -> dict[str, float]:
    scores = spatial_scores(h, p)
    return {"eval_loss": eval_loss, "d_topo": scores.d_topo, "d_metric": scores.d_metric}
