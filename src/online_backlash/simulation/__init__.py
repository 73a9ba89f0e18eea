"""Simulators: the rigs and the generated logs the tests, benches and demos run on, never the library's path.

* :mod:`.rig` -- a gearbox test rig by eq. (1): rig-like motion, play that may wear, quantised encoders;
* :mod:`.two_mass_rig` -- a two-mass drive with a compliant shaft and friction, a simulator the estimators do
  not assume;
* :mod:`.rig_logs` -- a simulated rig's recording as CAN frames, logs and serial captures;
* :mod:`.wear_logs` -- snapshot logs of a gearbox wearing against its hour meter;
* :mod:`.synthetic` -- known effects added to a recording, for the closing-the-loop tests and benches.

Until issue 29 these modules lived at the top level (``online_backlash.rig``, ...) and in
``online_backlash.diagnostics.synthetic``; those names still import them, with a DeprecationWarning.
"""
