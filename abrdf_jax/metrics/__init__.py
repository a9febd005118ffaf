"""Evaluation metrics of PROTOCOL.md: exposure, tone mapping, RMSE8/PSNR, ΔE76/ΔE2000, LogErr."""

from ._color import D65_WHITE_XYZ as D65_WHITE_XYZ
from ._color import D65_XY as D65_XY
from ._color import METRIC_KEYS as METRIC_KEYS
from ._color import SRGB_PRIMARIES_XY as SRGB_PRIMARIES_XY
from ._color import SRGB_TO_XYZ as SRGB_TO_XYZ
from ._metrics import delta_e76 as delta_e76
from ._metrics import delta_e76_pairs as delta_e76_pairs
from ._metrics import delta_e2000 as delta_e2000
from ._metrics import evaluate as evaluate
from ._metrics import evaluate_batch as evaluate_batch
from ._color import expose as expose
from ._metrics import log_error as log_error
from ._metrics import psnr as psnr
from ._metrics import rmse8 as rmse8
from ._color import srgb_decode as srgb_decode
from ._color import srgb_encode as srgb_encode
from ._color import srgb_to_lab as srgb_to_lab
from ._metrics import summarize as summarize
from ._color import tonemap as tonemap
