"""The ParaView figure of docs/outputs.md: a run folder's solid elements and cohesive elements
at its last output time, deformed, in ParaView's own renderer (not matplotlib).

    xvfb-run -a pvpython scripts/paraview_figure.py RUN_DIR OUT.png

RUN_DIR: a run folder with field output (for example results/tcb/adaptive of demos/tcb.py).
Needs a ParaView with its Python (Debian: ``apt-get install paraview``); the steps are those
of the "In ParaView" lists of docs/outputs.md.
"""

import sys
from pathlib import Path

from paraview.simple import (
    ColorBy,
    GetActiveCamera,
    GetActiveViewOrCreate,
    GetAnimationScene,
    GetColorTransferFunction,
    GetScalarBar,
    OpenDataFile,
    Render,
    SaveScreenshot,
    Show,
    WarpByVector,
)

run, png = Path(sys.argv[1]), Path(sys.argv[2])
scene = GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()
view = GetActiveViewOrCreate("RenderView")
view.ViewSize = [1400, 500]
view.OrientationAxesVisibility = 1
view.Background = [1.0, 1.0, 1.0]
view.UseColorPaletteForBackground = 0

elements = OpenDataFile(str(run / "elements.pvd"))
cohesive = OpenDataFile(str(run / "cohesive.pvd"))
scene.UpdateAnimationUsingDataTimeSteps()
scene.AnimationTime = elements.TimestepValues[-1]

solids = Show(WarpByVector(Input=elements, Vectors=["POINTS", "displacement"]), view)
solids.SetRepresentationType("Surface With Edges")
ColorBy(solids, ("CELLS", "first_ply"))
GetColorTransferFunction("first_ply").ApplyPreset("Cool to Warm", True)

cracks = Show(WarpByVector(Input=cohesive, Vectors=["POINTS", "displacement"]), view)
ColorBy(cracks, ("CELLS", "cohesive_damage"))
damage = GetColorTransferFunction("cohesive_damage")
damage.ApplyPreset("Inferno (matplotlib)", True)
damage.RescaleTransferFunction(0.0, 1.0)
bars = (
    ("first_ply", "first ply", 0.15, "%.0f"),
    ("cohesive_damage", "cohesive damage", 0.6, "%.1f"),
)
for name, title, x, label in bars:
    bar = GetScalarBar(GetColorTransferFunction(name), view)
    bar.Title, bar.ComponentTitle = title, ""
    bar.TitleColor = bar.LabelColor = [0.0, 0.0, 0.0]
    bar.Orientation = "Horizontal"
    bar.WindowLocation = "Any Location"
    bar.Position = [x, 0.05]
    bar.ScalarBarLength = 0.3
    bar.RangeLabelFormat = label
    bar.Visibility = 1

# from the front (-y), a little above and to the side: the arms, their sublaminates and,
# between them, the cohesive elements
view.CameraPosition = [-4.0, -12.0, 6.0]
view.CameraFocalPoint = [0.0, 0.0, 0.0]
view.CameraViewUp = [0.0, 0.0, 1.0]
view.ResetCamera()
GetActiveCamera().Zoom(2.6)
Render(view)
SaveScreenshot(str(png), view, ImageResolution=[1400, 500])
print(f"wrote {png}")
