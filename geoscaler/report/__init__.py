"""What users see of a job: reports, tables and strict JSON, pictures, progress bars and Ctrl-C, a
job run as a command runs it, and benchmarks over many meshes."""
