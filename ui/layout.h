#pragma once
// The studio window's layout: the viewer (or the Atlas panel) top left, the timeline under it,
// the side panel (Fit, Focus, Export, Log) on the right and a status line along the bottom.
// The splitters between them are dragged like in an editor; the window's size and the
// splitters' places are remembered in $XDG_CONFIG_HOME/refocus/studio_layout.json.
#include <string>

namespace refocus {

struct Layout {
    float side_w = 380.0f;      // the side panel's width
    float timeline_h = 236.0f;  // the timeline's height
    int window_w = 1280, window_h = 800;
    static constexpr float kStatusH = 24.0f;

    // Rectangles in screen px within the viewport (x, y, w, h), with the sizes kept usable.
    struct Rect {
        float x, y, w, h;
    };
    Rect viewer(float vx, float vy, float vw, float vh) const;
    Rect timeline(float vx, float vy, float vw, float vh) const;
    Rect side(float vx, float vy, float vw, float vh) const;
    Rect status(float vx, float vy, float vw, float vh) const;
    void clamp_to(float vw, float vh);
};

// Where the layout lives; "" when neither XDG_CONFIG_HOME nor HOME is set.
std::string layout_file();
// The remembered layout, or the defaults (a damaged file is ignored: it is rewritten on exit).
Layout load_layout();
void save_layout(const Layout& l);  // a read-only home is not an error

// The splitters between the panels, drawn over everything: hover shows the resize cursor,
// dragging moves them. Call once per UI frame, after the panels. True while dragging.
bool drag_splitters(Layout& l);

}  // namespace refocus
