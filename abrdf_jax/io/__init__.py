"""File input and output (public API): atomic writes, measurement CSV, ABRDF tables, MERL files."""

from ._tables import CSV_COLUMNS as CSV_COLUMNS
from ._tables import NPZ_KEY as NPZ_KEY
from ._tables import TABLE_SHAPE as TABLE_SHAPE
from ._tables import atomic_write as atomic_write
from ._tables import read_samples_csv as read_samples_csv
from ._tables import read_table as read_table
from ._tables import write_samples_csv as write_samples_csv
from ._tables import write_table as write_table
from ._merl import MERL_SCALE as MERL_SCALE
from ._merl import MERL_SHAPE as MERL_SHAPE
from ._merl import MERLMaterial as MERLMaterial
from ._merl import merl_bin_indices as merl_bin_indices
from ._merl import merl_lookup as merl_lookup
from ._merl import read_merl_binary as read_merl_binary
from ._merl import write_merl_binary as write_merl_binary
