"""Where a recording keeps what it makes: `<case>/windows/<window>/` (each window a case) and
`<case>/recording/` (the joined outputs). Spelt here once; read through `view.RecordingView`."""

RECORDING_DIR = "recording"
WINDOWS_DIR = "windows"
WINDOWS_FILE = "windows.json"
TRAJECTORY_FILE = "trajectory.json"
SUMMARY_FILE = "summary.json"
FRAMES_FILE = "frames.json"
DEPTH_DIR = "depth"
REPORT_FILE = "report.html"
MESH_FILE = "mesh.ply"
