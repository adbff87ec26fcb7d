"""``jaxstyle play``: steer a styled character live in the browser.

* :mod:`jaxstyle.play.session`: the browser-free state: a run's models (the 2018 PFNN, a trained
  2022 model) and their styles, characters, steering
  (click targets, waypoints, directions, keys) -> the controller's per-frame controls, one
  jitted step for all characters, style switches and blends, the recording buffer;
* :mod:`jaxstyle.play.learn`: learning a new style from a clip in a background thread (the
  few-shot sweep of Mason et al. 2018), with progress;
* :mod:`jaxstyle.play.server`: the viser web page, its scene and controls, the 60 Hz loop.
"""
