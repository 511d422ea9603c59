#pragma once
// The timeline under the viewer: play / pause, frame steps, the playhead slider, and one lane
// per focus parameter with its keyframes (key_lanes.h: select, move, copy, ease, delete).
#include "key_lanes.h"

#include <string>

namespace refocus {

struct StudioContext;

struct TimelineState {
    bool playing = false;
    int rate = 1;             // playback speed and direction: ±1, ±2, ±4, ±8 × the clip's fps
    double play_clock = 0.0;  // the time the frame shown was due, while playing
    KeyLaneState keys;
};

void toggle_playback(TimelineState& s);
// J / K / L as in editors: L plays forward (again: faster), J backward, K stops.
void shuttle(TimelineState& s, int direction);
// Moves the playhead as the clock says while playing, looping between the in and out points.
void advance_playback(TimelineState& s, StudioContext& ctx);
void set_in_point(StudioContext& ctx, int frame);
void set_out_point(StudioContext& ctx, int frame);
// "HH:MM:SS:FF" of a frame at the clip's fps (non-drop frame).
std::string timecode(int frame, double fps);
void draw_timeline(TimelineState& s, StudioContext& ctx);

}  // namespace refocus
