"""Sources above the driver layer: adapters that turn the simulator and the log readers
into :class:`imudiag.drivers.Source` transports.

``sim://`` (:mod:`.sim`) and ``replay://`` (:mod:`.replay`) are registered into the
driver registry through the ``imudiag.sources`` entry-point group (pyproject.toml), the
way python-can finds its interfaces: the driver layer at the bottom of the house never
imports the simulator or the logs. A plug-in package adds a scheme the same way::

    [project.entry-points."imudiag.sources"]
    myboard = "myboard.source:MyBoardSource"
"""
