"""Contracts between node kinds: the shapes and helpers that several kinds agree on.

Any kind may import these modules (and only these, besides its own and ``stereograph.api``):

* :mod:`nodes.contracts.arm` -- the ``ArmModel`` (joints, forward kinematics, servo-unit mapping
  of the AX-12A); made by ``ik.arm``, read by the IK solvers and the actuators.
* :mod:`nodes.contracts.views` -- rectified views served on request (``RectifiedView``); made
  from a ``Rectification`` and a pair, read by the segmenters.
* :mod:`nodes.contracts.board` -- calibration board definitions (ChArUco); used by the synthetic
  renderer and the ChArUco calibrator.
* :mod:`nodes.contracts.calibration_file` -- reading back a saved artifact and the rig
  fingerprint that ties a model to the rig it was fitted on; calibrators, compensators, locators.
* :mod:`nodes.contracts.recording` -- the ``StereoRecording`` lossless video files; camera
  sources and recorders.

* :mod:`nodes.contracts.cv_overloads` -- stop signals held across an OpenCV call that tries more
  than one overload (the binding would crash on one); any kind that calls OpenCV.
* :mod:`nodes.contracts.records` -- the shape checks of the records kinds hand each other
  (``Segmentation``, ``Disparity``, ``Location``, the pairs), registered with the engine when any
  contract is imported, so a malformed record fails the node that made it.

``tests/test_node_contracts.py`` walks every import under ``nodes/`` and fails when a kind imports
another kind's private (``_``-prefixed) module.
"""

from nodes.contracts import records as _records  # noqa: F401  (registers the checks)
