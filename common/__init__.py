"""The ground floor every package stands on: user errors, checks, commands, files, processes.

User errors and the checks that raise them, the one-line end of a command, outputs never
half-written, helper processes that end with their command.

Nothing here knows cloth, tissue, a renderer or a model: it imports only the standard library
(and, inside the functions that need them, torch, OmegaConf, tqdm or joblib), and every other
package may import it (an import-linter contract in CI).
"""

import os

# Before anything loads OpenMP (torch, numba): waiting threads sleep instead of spinning, so a
# process with several threads survives a busy CPU (see simulator.threads). OpenMP reads it
# when it loads, so it reaches the helper processes of every command too.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
