"""The job: argument checks, the one pipeline every command runs, the downsampling job, result rows
and the asset as it ships."""
