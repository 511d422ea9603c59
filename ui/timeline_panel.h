#pragma once
// The timeline under the viewer: play / pause, frame steps, the playhead slider, and one lane
// per focus parameter with its keyframes (key_lanes.h: select, move, copy, ease, delete).
#include "key_lanes.h"

namespace refocus {

struct StudioContext;

struct TimelineState {
    bool playing = false;
    double play_clock = 0.0;  // the time the frame shown was due, while playing
    KeyLaneState keys;
};

void toggle_playback(TimelineState& s);
void draw_timeline(TimelineState& s, StudioContext& ctx);

}  // namespace refocus
