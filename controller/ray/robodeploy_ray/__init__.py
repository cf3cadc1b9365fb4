"""robodeploy on a Ray cluster: `robodeploy batch` (clips × seeds on the mirror, lockstep, so every
run is deterministic) and `robodeploy check --clip` (motion quality) spread over a cluster's CPUs.

The driver ships the robodeploy binary, its native libraries, the robot, the policy, the clips and
the mirror file to the workers as one bundle (Ray's runtime environment `working_dir`), splits the
work into tasks of a few seconds each, gathers every run's row as it arrives (appended to
`results.jsonl`, so a stopped job resumes where it stopped) and writes one table and one report.
"""

__version__ = "0.1.0"
