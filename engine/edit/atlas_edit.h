#pragma once
// Atlas editing (paper Fig. 1: "we edit our background atlas ... these simple edits propagate to
// the entire video"). An edit is an RGBA layer (straight alpha) over a fitted atlas, so that
// training can go on under it and a refit keeps the artist's work: result = edit over base.
// Frames see it through the mappings: the delta result − base is sampled through each frame's
// UV and the sharp frame recomposed with paper eq. 1 (apply_edits).
//
// Not thread-safe: one thread (the studio's UI thread, or a CLI) owns an editor.
#include <torch/types.h>

#include <array>
#include <cstdint>
#include <deque>
#include <string>

#include "model/fit_model.h"
#include "io/image.h"
#include "io/image_file.h"
#include "project/project.h"

namespace refocus {

struct Brush {
    enum Mode { Paint, Erase, Clone };
    float color[3] = {1.0f, 1.0f, 1.0f};  // linear RGB
    float size = 16.0f;                   // diameter, atlas px
    float hardness = 0.8f;                // 0 (soft falloff from the centre) .. 1 (hard edge)
    float opacity = 1.0f;                 // max coverage within a stroke (flow 100%)
    Mode mode = Paint;
    float clone_dx = 0.0f, clone_dy = 0.0f;  // Clone: source = target + (dx, dy)
};

// Coverage of a round dab of `size` and `hardness` at distance `d` px from its centre, in [0,1].
float dab_coverage(float d, float size, float hardness);

class AtlasEditor {
  public:
    // The fitted atlas (3-channel linear; 1/4 channels are converted). May be called again as
    // training updates it: the edit is kept. The first call sizes an empty edit; a loaded edit
    // of another size is refused (refocus::Error naming its file and both sizes) unless empty.
    void set_base(const Image& base);
    const Image& base() const { return m_base; }
    const Image& edit() const { return m_edit; }  // RGBA, straight alpha, atlas size
    Image result() const;                         // edit over base
    bool has_edits() const;
    int width() const { return m_edit.width; }
    int height() const { return m_edit.height; }
    int64_t version() const { return m_version; }  // bumps on every change

    // Strokes, in atlas pixels (pixel (i, j) covers [i, i+1) × [j, j+1)). Within a stroke the
    // coverage is the max over its dabs (no build-up where dabs overlap); strokes build up.
    void begin_stroke(const Brush& brush);
    void dab(float x, float y);
    void stroke_to(float x, float y);  // dabs spaced ~size/4 from the last point to (x, y)
    void end_stroke();                 // one undo step (its dirty rectangle only)
    bool in_stroke() const { return m_in_stroke; }

    void undo();
    void redo();
    bool can_undo() const { return !m_undo.empty(); }
    bool can_redo() const { return !m_redo.empty(); }
    void set_undo_limit(size_t bytes);  // default 256 MB; the oldest steps are dropped
    size_t undo_bytes() const { return m_history_bytes; }

    // Eyedropper: result() at the pixel holding (x, y) (clamped to the atlas).
    std::array<float, 3> pick(float x, float y) const;

    // A repainted atlas (PNG / TIFF / EXR, atlas size) becomes the edit where it differs from
    // the base by more than 1/255 in sRGB (alpha 1 there, 0 elsewhere): one undoable step.
    // Returns the number of edited pixels.
    int64_t import_image(const std::string& path);
    void export_image(const std::string& path, PixelFormat format) const;  // writes result()
    void clear();  // removes every edit (one undoable step)

    // The edit layer as a file (RGBA float EXR, atomic); load_edit clears the history and
    // checks the size against the base when there is one.
    void load_edit(const std::string& path);
    void save_edit(const std::string& path) const;
    const std::string& label() const { return m_label; }  // the edit's file (for messages)

    // result − base for an atlas tensor [3,Ha,Wa] as [1,3,Ha,Wa]: α·(edit − base); undefined
    // without edits. Refuses a base of another size (naming the edit's file).
    torch::Tensor delta(const torch::Tensor& base_chw) const;

  private:
    friend struct ProjectEdits;
    struct Rect {
        int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // [x0,x1) × [y0,y1)
        bool empty() const { return x1 <= x0 || y1 <= y0; }
        void add(const Rect& o);
    };
    struct Step {
        Rect r;
        std::vector<float> before, after;  // RGBA of the edit inside r
        size_t bytes() const { return (before.size() + after.size()) * sizeof(float); }
    };
    void check_size(int w, int h, const char* what) const;
    std::vector<float> crop(const Image& img, const Rect& r) const;
    void paste(Image& img, const Rect& r, const std::vector<float>& px);
    void push_step(Step s);
    void replace_edit(Image next);  // undoable, dirty rectangle = where it differs
    void stroke_pixel(int x, int y, float cov);
    std::array<float, 3> result_at(int x, int y, bool pre_stroke) const;

    Image m_base, m_edit;
    std::string m_label;
    int64_t m_version = 0;
    mutable int64_t m_has_version = -1;
    mutable bool m_has = false;

    // Stroke state: per-pixel max coverage and the edit before the stroke (valid where cov > 0).
    Brush m_brush;
    bool m_in_stroke = false, m_have_last = false;
    float m_last_x = 0, m_last_y = 0, m_carry = 0;
    std::vector<float> m_cov;
    Image m_before;
    Rect m_dirty;

    std::deque<Step> m_undo, m_redo;
    size_t m_history_bytes = 0, m_history_limit = size_t(256) << 20;
};

// A project's edits: <project>/edits/edit_bg.exr and edit_fg.exr, listed in project.json's
// "edits" section. Missing files mean no edits.
struct ProjectEdits {
    AtlasEditor bg, fg;
    AtlasEditor& layer(int i) { return i == 0 ? bg : fg; }
    const AtlasEditor& layer(int i) const { return i == 0 ? bg : fg; }
    bool has_edits() const { return bg.has_edits() || fg.has_edits(); }

    static fs::path file_of(const Project& project, int layer);  // 0 bg, 1 fg
    static ProjectEdits load(const Project& project);
    // Writes the layers with edits (removes the files of those without) and updates
    // project.sections["edits"] and project.json, so that later saves of `project` keep it.
    void save(Project& project) const;
    // The same from edit layers alone (RGBA, null: no edit), so that a snapshot can be written
    // on another thread (the studio's autosave) while the editors go on.
    static void save_layers(Project& project, const Image* bg_edit, const Image* fg_edit);
};

// Adds the edit deltas (AtlasEditor::delta, [1,3,Ha,Wa]; undefined = no edit) to a rendered
// batch: sampled through L.uv_bg / L.uv_fg (bilinear, align_corners = false, border padding,
// the fit's grid convention) onto bg / fg, then sharp = α·fg + (1−α)·bg (paper eq. 1).
// Exactly a no-op when both are undefined.
void apply_edits(Layers& L, const torch::Tensor& bg_delta, const torch::Tensor& fg_delta);

}  // namespace refocus
