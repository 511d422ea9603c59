#pragma once
// The viewer's pictures, made off the UI thread. The UI posts the scene (view_modes.h) and what
// it wants (modes, the playhead, whether to render ahead); a thread of its own reads the input
// frames, asks the fit worker for each frame's layers (FitWorker::frame_async), renders the
// mode (GLSL on a hidden window's context, or the CPU twin) and keeps the results as RGBA8 in a
// cache bounded in bytes. The UI shows the newest picture of the playhead that is ready and
// never waits: a stale picture stays up until the new one arrives, a playhead that moved past
// what is rendered shows the last frame (playback drops frames instead of freezing).
//
// Order of work: the playhead first — a half-resolution pass when a full one is slow, then the
// full one — then the frames after it, around the clip, so playback finds them cached.
#include <atomic>
#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "gl_texture.h"
#include "view_modes.h"

struct GLFWwindow;

namespace refocus {
class FrameSource;
}

namespace refocus {

struct RenderedFrame {
    int mode = 0, frame = 0;
    uint64_t generation = 0;  // the scene's (0: a mode that does not depend on it)
    bool full = true;         // false: the progressive half-resolution pass
    int divisor = 1;          // the proxy it was made at: 1 full size, 2 half, 4 quarter
    int width = 0, height = 0;
    std::vector<unsigned char> rgba;  // sRGB, RGBA8
    uint64_t hash = 0;                // of rgba: playback counts distinct pictures with it
    std::shared_ptr<const FitWorker::ViewFrame> view;  // the layers it was made from, if any
};

class ViewRenderer {
  public:
    enum class Backend { Auto, Gpu, Cpu };
    // `offscreen`: a hidden GLFW window whose context the thread makes its own (null: CPU only).
    // `gl_renderer`: GL_RENDERER of the studio's context, for Backend::Auto.
    ViewRenderer(FitWorker& worker, GLFWwindow* offscreen, std::string gl_renderer);
    ~ViewRenderer();
    ViewRenderer(const ViewRenderer&) = delete;
    ViewRenderer& operator=(const ViewRenderer&) = delete;

    // The project whose frames to show (its folder, frame count and width); drops the cache.
    void open(const std::string& project_dir, int frames, int width);
    // Proxy size of the pictures: 0 auto (at most 1280 px wide), 1 full, 2 half, 4 quarter.
    // Exports always render at full size.
    void set_proxy(int proxy);
    int proxy() const { return m_proxy; }
    std::string proxy_name() const;
    void set_scene(const ViewScene& scene);
    // `modes`: indexes into view_modes(); `ahead`: render the frames after the playhead too.
    void set_wanted(const std::vector<int>& modes, int playhead, bool ahead);
    void set_backend(Backend b);
    Backend backend() const { return m_backend; }
    // The GLSL depth of field: Fast (the default: playback and scrubbing at frame rate on
    // software GL) or Exact (the reference gather, what exports compute). The CPU twin is exact.
    void set_quality(PreviewQuality q);
    PreviewQuality quality() const { return m_quality; }
    std::string backend_name() const;

    // The fit's layers at `frame` for the scene last posted, once rendered (click-to-focus reads
    // depth through them), or null.
    std::shared_ptr<const FitWorker::ViewFrame> layers_at(int frame) const;
    // The newest picture of (mode, frame), or null.
    std::shared_ptr<const RenderedFrame> get(int mode, int frame) const;
    // True when (mode, frame) is rendered in full for the scene last posted.
    bool current(int mode, int frame) const;
    // Frames of `mode` rendered in full for the scene last posted, of the clip's.
    int cached_frames(int mode) const;
    std::string take_error();
    double last_full_ms(int mode) const;

  private:
    struct Work {
        int mode = -1, frame = -1;
        double scale = 1.0;
    };
    void loop();
    bool next_work(Work& w);  // under m_mutex
    void update_divisor();    // under m_mutex
    bool needs(int mode, int frame, bool full_only) const;
    void render(const Work& w);
    std::shared_ptr<const FitWorker::ViewFrame> layers(int frame, uint64_t maps_generation);
    PreviewBackend& preview();
    void store(std::shared_ptr<RenderedFrame> f);
    void evict();

    FitWorker& m_worker;
    GLFWwindow* m_offscreen;
    std::string m_gl_renderer;
    std::atomic<Backend> m_backend{Backend::Auto};
    std::atomic<PreviewQuality> m_quality{PreviewQuality::Fast};

    mutable std::mutex m_mutex;
    std::condition_variable m_cv;
    bool m_quit = false, m_failed = false;
    std::string m_dir;
    int m_frames = 0, m_width = 0;
    std::atomic<int> m_proxy{0};
    int m_divisor = 1;
    uint64_t m_epoch = 0;  // bumps with open(): work of an older project is dropped
    ViewScene m_scene;
    std::shared_ptr<const ViewScene> m_scene_ptr;
    std::vector<int> m_modes;
    int m_playhead = 0;
    bool m_ahead = false;
    std::map<std::pair<int, int>, std::shared_ptr<const RenderedFrame>> m_cache;
    size_t m_cache_bytes = 0;
    std::map<int, double> m_full_ms;
    std::string m_error;

    // Layers per frame, filled by the thread (they change only with the fit's atlases).
    std::map<int, std::shared_ptr<const FitWorker::ViewFrame>> m_layers;
    uint64_t m_layers_generation = 0;
    std::set<std::pair<uint64_t, int>> m_layers_tried;  // asked for once per generation

    // The thread's own.
    std::unique_ptr<FrameSource> m_source;
    std::string m_source_dir;
    std::unique_ptr<PreviewBackend> m_cpu, m_gpu;
    std::string m_gpu_error;
    std::thread m_thread;
};

}  // namespace refocus
