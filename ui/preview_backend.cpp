#include "preview_backend.h"

#include "gl_preview.h"

namespace refocus {

namespace {

// Layers as the export composes them: the fit's own when nothing is edited, else paper eq. 1
// over the edited atlases.
PreviewLayers layers_of(const FrameMaps& m, const EditAtlases& e, int threads) {
    const bool two = !m.fg.empty();
    if (e.bg && !m.uv_bg.empty())
        return composite_layers(*e.bg, m.uv_bg, two && e.fg ? *e.fg : Image(),
                                two ? m.uv_fg : Image(), two ? m.alpha : Image(), threads, m.bg_fix,
                                two ? m.fg_fix : Image());
    return preview_layers(m);
}

class CpuPreview : public PreviewBackend {
  public:
    explicit CpuPreview(int threads) : m_threads(threads) {}
    const char* name() const override { return "CPU"; }
    Image render(const FrameMaps& m, const EditAtlases& e, const PreviewDepth* depth,
                 const PreviewLens& lens) override {
        PreviewLayers l = layers_of(m, e, m_threads);
        if (!depth || lens.aperture <= 0.0) return l.composite;
        return render_dof(l, *depth, lens, m_threads);
    }

  private:
    int m_threads;
};

class GlslPreview : public PreviewBackend {
  public:
    const char* name() const override { return "GPU (GLSL)"; }
    Image render(const FrameMaps& m, const EditAtlases& e, const PreviewDepth* depth,
                 const PreviewLens& lens) override {
        if (!e.bg || m.uv_bg.empty()) return m.sharp;  // atlases not received yet, or none
        if (e.version != m_edits_version) {
            m_gl.set_atlases(*e.bg, m.fg.empty() || !e.fg ? Image() : *e.fg);
            m_edits_version = e.version;
        }
        m_gl.set_frame(m.uv_bg, m.uv_fg, m.alpha);
        m_gl.set_frame_fix(m.bg_fix, m.fg.empty() ? Image() : m.fg_fix);
        PreviewLens l = lens;
        if (depth)
            m_gl.set_depth(*depth);
        else
            l.aperture = 0.0;
        m_gl.render(l, m_quality);
        return m_gl.read_result();  // waits for the GPU: the render's full cost
    }
    void set_quality(PreviewQuality q) override { m_quality = q; }

  private:
    GlPreview m_gl;
    int64_t m_edits_version = -2;
    PreviewQuality m_quality = PreviewQuality::Fast;
};

}  // namespace

std::unique_ptr<PreviewBackend> make_cpu_preview(int threads) {
    return std::make_unique<CpuPreview>(threads);
}

std::unique_ptr<PreviewBackend> make_gl_preview() {
    return std::make_unique<GlslPreview>();
}

bool is_software_gl(const std::string& r) {
    for (const char* s : {"llvmpipe", "softpipe", "swrast", "Software"})
        if (r.find(s) != std::string::npos) return true;
    return false;
}

}  // namespace refocus
