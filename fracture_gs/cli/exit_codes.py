"""Exit statuses shared by ``evaluate.py`` and ``demo.py``: bad input (an output folder that
cannot be made included) is one ``error: ...`` line and status 2, a failed simulation or a
failed write (a full disk) 1, Ctrl-C 130."""
from __future__ import annotations

import sys
from collections.abc import Callable


def run_guarded(function: Callable[[], int | None], interrupted: str) -> int:
    """Call ``function`` and turn the project's input errors into exit statuses."""
    from fracture_gs._backend import KernelBoundError
    from fracture_gs.pipeline.experiments.runner import RunFailed
    from fracture_gs.pipeline.experiments.sim_eval import EvaluationError
    from fracture_gs.io.device import DeviceError
    from fracture_gs.io.lock import FolderBusy
    from fracture_gs.io.manifest import FolderTaken
    from fracture_gs.io.model_layout import ModelError
    from fracture_gs.io.output_folder import OutputFolderError, os_error_line
    from fracture_gs.folders.sim_reader import SimulationError
    from fracture_gs.render.views import ViewSpecError

    try:
        status = function()
    except (EvaluationError, ModelError, SimulationError, ViewSpecError, OutputFolderError,
            DeviceError, FolderBusy, FolderTaken) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (RunFailed, KernelBoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # writing a result failed (disk full, folder removed, ...)
        print(f"error: {os_error_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(interrupted, file=sys.stderr)
        return 130
    return 0 if status is None else int(status)
