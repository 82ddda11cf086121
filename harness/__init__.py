"""SGSRT HIL harness: loop, controllers, shaping, identification, recording, CLI."""

import os

# The harness's matrices are small (8 x 8 plant, at most a few hundred dofs in the reference
# models): threaded BLAS only adds overhead, and with a process per core (sweep) it
# oversubscribes the machine (measured 10x slower on 2 cores). Must precede numpy's import.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

# Recordings are written without an RRD footer on purpose (harness.record.recording: its manifest
# grows with the run); Rerun warns about that on every file. Only that module's warnings are
# silenced, only when RUST_LOG is unset. Must precede rerun's import. The file sink's and the
# stream's own errors too: a write that fails (a full disk) is caught by the recorder's flush
# and said in one line naming the folder (harness.record.output.OutputError), where Rerun
# printed two more of its own.
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=off,"
                      "re_sdk::recording_stream=off")
