"""Pure signal-processing stages of the angular fingerprinting pipeline.

Each module is one stage with numpy arrays in and out and its streaming state passed in
and returned (scipy.signal style); nothing here reads files, prints or logs to a device:

pulses       direct-coupling edge tracking, cutting into aligned, gated pulses
gate         one-way range window <-> sample indices
rangedoppler FFT along pulses (reference time and pictures only)
period       blade-pass frequency estimate, refined well below one FFT bin
fingerprint  angular table by folding, vectorised nearest-phase matching
tracking     circular Kalman filter on (phase, phase rate)
aliasing     rates near p/q cycles per pulse: which alias line fits the table best
decide       direction, rate and confidence from the track and the motion evidence
"""
