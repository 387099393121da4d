"""Which current of a model the apps and the media callback look at (models.loading.current_to_view): a single
current, a family's member of a given training shape with that shape's own code and boundary, or a clear
error."""

import pytest
import torch

from deepcurrents.errors import ConfigError
from deepcurrents.models.loading import CheckpointError, current_to_view, viewable_current


class Single(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.current = torch.nn.Linear(3, 1)


class Family(torch.nn.Module):
    """Duck-typed like the autodecoder: member(code, loops), latent(i), shape_loops(i), check_shape_index."""

    num_shapes = 3

    def latent(self, i):
        return torch.full((2,), float(i))

    def shape_loops(self, i):
        return [torch.full((4, 3), 10.0 * i)]

    def member(self, code, loops):
        return ("member", float(code[0]), float(loops[0][0, 0]))

    def check_shape_index(self, index, name="latent"):
        if not 0 <= index < self.num_shapes:
            raise ConfigError(f"{name}={index!r} is not a training shape.")
        return int(index)


def test_single_current_and_family_members():
    single = Single()
    assert current_to_view(single) is single.current
    family = Family()
    assert current_to_view(family) == ("member", 0.0, 0.0)  # shape 0 by default
    assert current_to_view(family, 2) == ("member", 2.0, 20.0)  # its own code and its own boundary


def test_what_cannot_be_viewed_says_why():
    with pytest.raises(ValueError, match="shape=1 was given, but this Single holds a single current"):
        current_to_view(Single(), 1)
    with pytest.raises(CheckpointError, match=r"shape=1 picks one shape of a family, but ckpt_path='s\.ckpt' holds "
                                              r"a single current; leave shape unset\."):
        viewable_current(Single(), "s.ckpt", 1)
    with pytest.raises(ConfigError, match="shape=5 is not a training shape"):
        viewable_current(Family(), "f.ckpt", 5)  # the model's own sentence, not wrapped
    with pytest.raises(CheckpointError, match="ckpt_path='x.ckpt' has no current to look at: a Module has neither"):
        viewable_current(torch.nn.Module(), "x.ckpt")
