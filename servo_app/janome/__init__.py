"""Janome JR3000 / JC-3 / JS3: the point-job link (protocol, profiles, kinematics, session, servo process).

Parent-side handle: :class:`servo_app.janome.runner.JanomeProcess` (the same interface as the FANUC
``StreamProcess``). See docs/janome.md.
"""
