"""The outputs of the load-path cases (and of cases with a solve hook) computed from the
ranks' pieces against the whole problem's, for the same solved path (for
test_distributed.py): python mpi_outputs_paths.py CASE:LEVEL[:NAME=VALUE,...] ...

Every rank builds its part and solves the case as `nitsche run` does under mpirun
(Case.solve on the DistributedProblem: its load path or solve hook); then, as `nitsche
run` does, every rank computes the case's errors, report and figures and solution.png's
pictures on its part (nitsche.commands.part, inside nitsche.partition.local), and rank 0
computes them again on the whole problem rebuilt with the path's steps
(nitsche.commands.whole, what `nitsche run` did before the case declared
OUTPUTS_FROM_PIECES).  Rank 0 prints one JSON line per case: both errors, the largest
relative differences of the report hooks' numbers (seconds left out), of the values the
figures draw (FIGURE_DATA) and of the multiplier pictures, the figures each wrote, a load
path's steps (time, Newton iterations, energy, cuts: for the serial path's) and whether a
pairing in the current configuration grew a rank's Hessian pattern (ironing).  The whole
problem of such a pairing is paired at the solution, as the ranks' parts are."""
import json
import os
import sys
import tempfile

from nitsche import cases, commands, partition
from nitsche.distributed import DistributedProblem
from nitsche.plot import multiplier_picture

from mpi_outputs import difference, report_difference

# what the cases' figures draw (the report hooks hold the rest: force_depth, forces)
FIGURE_DATA = {
    "friction": lambda m, problem, r, p: list(m.tractions(problem, r, p)),
}


def main(specs):
    for spec in specs:
        name, level, *sets = spec.split(":")
        case = cases.get(name)
        p = case.parameters(dict(kv.split("=") for s in sets for kv in s.split(",")))
        degree = case.degrees[0]
        dp = DistributedProblem.build(lambda: case.problem(int(level), degree, p))
        entries = dp.local.assembler.nnz
        solved = case.solve(dp, None)  # (solver auto, as `nitsche run`)
        grew = dp.comm.allreduce(dp.local.assembler.nnz > entries)
        folder = tempfile.mkdtemp() if dp.rank == 0 else None
        hook = getattr(case.module, "figures", lambda *a: [])
        report = getattr(case.module, "report", lambda *a: {})
        drawn = FIGURE_DATA.get(name, lambda *a: [])
        problem, result = commands.part(dp, solved)
        with partition.local(dp.comm):
            errors = case.errors(problem, result, p)
            extra = report(problem, result, p)
            drawn_pieces = drawn(case.module, problem, result, p)
            figures = hook(problem, result, p, folder)
            local = problem.constraint_values(result.x)
            pictures = {c: multiplier_picture(local[c]) for c in local}
        if dp.rank > 0:
            continue
        whole, serial = commands.whole(case, dp, solved, degree, p)
        whole.update_pairing(serial.x)
        os.makedirs(os.path.join(folder, "whole"))
        whole_errors = case.errors(whole, serial, p)
        whole_report = report(whole, serial, p)
        whole_drawn = drawn(case.module, whole, serial, p)
        whole_figures = hook(whole, serial, p, os.path.join(folder, "whole"))
        values = whole.constraint_values(serial.x)
        print(json.dumps(dict(
            case=name, converged=bool(solved.converged), errors=errors, serial_errors=whole_errors,
            steps=len(getattr(dp, "path", None).steps) if hasattr(dp, "path") else None,
            path=[[s["time"], s["iterations"], s["energy"], s["cuts"]] for s in dp.path.steps]
            if hasattr(dp, "path") else None, pattern_grew=bool(grew),
            pictures={c: pictures[c][0] for c in pictures},
            picture_differences={c: difference(pictures[c], multiplier_picture(values[c]))
                                 for c in values},
            report_keys=sorted(extra), report_difference=report_difference(extra, whole_report),
            figure_data_difference=report_difference(drawn_pieces, whole_drawn),
            figures=[os.path.basename(f) for f in figures if os.path.getsize(f)],
            whole_figures=[os.path.basename(f) for f in whole_figures])), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
