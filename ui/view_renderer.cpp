#include "view_renderer.h"

#include <GLFW/glfw3.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>

#include "frame_source.h"

namespace refocus {

namespace {

// Pictures kept, in bytes of RGBA8: a 320×180 clip keeps every frame of several modes, a 1080p
// one about 60 frames.
constexpr size_t kCacheBytes = size_t(512) << 20;
// Layers kept per frame for the renders (they change only with the fit's atlases).
constexpr size_t kLayersBytes = size_t(768) << 20;
// A full render slower than this first shows a half-resolution pass.
constexpr double kProgressiveMs = 60.0;

double now_ms() {
    using namespace std::chrono;
    return duration<double, std::milli>(steady_clock::now().time_since_epoch()).count();
}

uint64_t fnv1a(const std::vector<unsigned char>& v) {
    uint64_t h = 1469598103934665603ull;
    for (unsigned char c : v) h = (h ^ c) * 1099511628211ull;
    return h;
}

// Every second pixel of every second row (UV maps must not be blended across layer edges).
Image half(const Image& a) {
    if (a.empty()) return a;
    Image o((a.width + 1) / 2, (a.height + 1) / 2, a.channels);
    for (int y = 0; y < o.height; ++y)
        for (int x = 0; x < o.width; ++x)
            for (int c = 0; c < a.channels; ++c) o.at(x, y, c) = a.at(2 * x, 2 * y, c);
    return o;
}

FitWorker::ViewFrame half(const FitWorker::ViewFrame& v) {
    FitWorker::ViewFrame o;
    o.t = v.t;
    o.atlas_version = v.atlas_version;
    const FrameMaps& m = v.maps;
    o.maps = {half(m.sharp), half(m.bg),    half(m.fg),     half(m.alpha),
              half(m.uv_bg), half(m.uv_fg), half(m.bg_fix), half(m.fg_fix)};
    o.radius = half(v.radius);
    return o;
}

size_t layer_bytes(const FitWorker::ViewFrame& v) {
    const FrameMaps& m = v.maps;
    size_t n = 0;
    for (const Image* i :
         {&m.sharp, &m.bg, &m.fg, &m.alpha, &m.uv_bg, &m.uv_fg, &m.bg_fix, &m.fg_fix, &v.radius})
        n += i->pixels.size() * sizeof(float);
    return n;
}

}  // namespace

ViewRenderer::ViewRenderer(FitWorker& worker, GLFWwindow* offscreen, std::string gl_renderer)
    : m_worker(worker), m_offscreen(offscreen), m_gl_renderer(std::move(gl_renderer)) {
    m_scene_ptr = std::make_shared<ViewScene>(m_scene);
    m_thread = std::thread([this] { loop(); });
}

ViewRenderer::~ViewRenderer() {
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        m_quit = true;
    }
    m_cv.notify_all();
    m_thread.join();
}

void ViewRenderer::open(const std::string& dir, int frames, int width) {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_dir = dir;
    m_frames = frames;
    m_width = width;
    update_divisor();
    ++m_epoch;
    m_failed = false;
    m_layers.clear();
    m_layers_tried.clear();
    m_cache.clear();
    m_cache_bytes = 0;
    m_full_ms.clear();
    m_playhead = 0;
    m_cv.notify_all();
}

void ViewRenderer::set_scene(const ViewScene& s) {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_scene = s;
    m_scene_ptr = std::make_shared<ViewScene>(s);
    m_cv.notify_all();
}

void ViewRenderer::set_wanted(const std::vector<int>& modes, int playhead, bool ahead) {
    std::lock_guard<std::mutex> lk(m_mutex);
    if (modes == m_modes && playhead == m_playhead && ahead == m_ahead) return;
    m_modes = modes;
    m_playhead = playhead;
    m_ahead = ahead;
    m_cv.notify_all();
}

void ViewRenderer::set_backend(Backend b) {
    m_backend = b;
    std::lock_guard<std::mutex> lk(m_mutex);
    m_scene.generation += 1;  // every picture again, with the other renderer
    m_scene_ptr = std::make_shared<ViewScene>(m_scene);
    m_cv.notify_all();
}

void ViewRenderer::set_quality(PreviewQuality q) {
    m_quality = q;
    std::lock_guard<std::mutex> lk(m_mutex);
    m_scene.generation += 1;  // every refocused picture again, at the other quality
    m_scene_ptr = std::make_shared<ViewScene>(m_scene);
    m_cv.notify_all();
}

void ViewRenderer::set_proxy(int proxy) {
    std::lock_guard<std::mutex> lk(m_mutex);
    m_proxy = proxy;
    update_divisor();
    m_cv.notify_all();
}

// Auto keeps the pictures at most 1280 px wide: a 1080p clip previews at ½, a 4K one at ¼.
void ViewRenderer::update_divisor() {
    int d = m_proxy;
    if (d <= 0) {
        d = 1;
        while (m_width / d > 1280 && d < 4) d *= 2;
    }
    if (d != m_divisor) m_full_ms.clear();
    m_divisor = d;
}

std::string ViewRenderer::proxy_name() const {
    std::lock_guard<std::mutex> lk(m_mutex);
    const char* size = m_divisor == 1 ? "full" : m_divisor == 2 ? "1/2" : "1/4";
    return m_proxy <= 0 ? std::string("auto (") + size + ")" : std::string(size);
}

std::string ViewRenderer::backend_name() const {
    const Backend b = m_backend;
    if (b == Backend::Cpu || !m_offscreen) return "CPU";
    const char* q = m_quality == PreviewQuality::Fast ? ", fast" : ", exact";
    if (b == Backend::Gpu) return std::string("GPU (GLSL") + q + ")";
    return is_software_gl(m_gl_renderer) ? std::string("GLSL (auto; software GL") + q + ")"
                                         : std::string("GPU (GLSL, auto") + q + ")";
}

std::shared_ptr<const FitWorker::ViewFrame> ViewRenderer::layers_at(int frame) const {
    std::lock_guard<std::mutex> lk(m_mutex);
    if (m_layers_generation != m_scene.maps_generation) return nullptr;
    auto it = m_layers.find(frame);
    return it == m_layers.end() ? nullptr : it->second;
}

std::shared_ptr<const RenderedFrame> ViewRenderer::get(int mode, int frame) const {
    std::lock_guard<std::mutex> lk(m_mutex);
    auto it = m_cache.find({mode, frame});
    return it == m_cache.end() ? nullptr : it->second;
}

bool ViewRenderer::current(int mode, int frame) const {
    std::lock_guard<std::mutex> lk(m_mutex);
    return !needs(mode, frame, true);
}

int ViewRenderer::cached_frames(int mode) const {
    std::lock_guard<std::mutex> lk(m_mutex);
    int n = 0;
    for (int t = 0; t < m_frames; ++t) n += !needs(mode, t, true);
    return n;
}

std::string ViewRenderer::take_error() {
    std::lock_guard<std::mutex> lk(m_mutex);
    return std::exchange(m_error, std::string());
}

double ViewRenderer::last_full_ms(int mode) const {
    std::lock_guard<std::mutex> lk(m_mutex);
    auto it = m_full_ms.find(mode);
    return it == m_full_ms.end() ? 0.0 : it->second;
}

// Whether (mode, frame) still has to be rendered for the scene posted (in full: `full_only`).
bool ViewRenderer::needs(int mode, int frame, bool full_only) const {
    auto it = m_cache.find({mode, frame});
    if (it == m_cache.end()) return true;
    const RenderedFrame& f = *it->second;
    const bool scene_free = !view_modes()[mode].needs_fit;
    if (!scene_free && f.generation != m_scene.generation) return true;
    if (f.divisor != m_divisor) return full_only || f.divisor < m_divisor;
    return full_only && !f.full;
}

bool ViewRenderer::next_work(Work& w) {
    if (m_failed || m_dir.empty() || m_frames <= 0 || m_modes.empty()) return false;
    const int t0 = std::clamp(m_playhead, 0, m_frames - 1);
    for (int m : m_modes)
        if (needs(m, t0, false)) {
            auto it = m_full_ms.find(m);
            const bool slow = it != m_full_ms.end() && it->second > kProgressiveMs;
            const double full = 1.0 / m_divisor;
            w = {m, t0, slow && view_modes()[m].needs_fit ? full / 2 : full};
            return true;
        }
    for (int m : m_modes)
        if (needs(m, t0, true)) {
            w = {m, t0, 1.0 / m_divisor};
            return true;
        }
    if (m_scene.fitted && !m_layers_tried.count({m_scene.maps_generation, t0}) &&
        !(m_layers_generation == m_scene.maps_generation && m_layers.count(t0))) {
        m_layers_tried.insert({m_scene.maps_generation, t0});
        w = {-1, t0, 1.0};
        return true;
    }
    if (!m_ahead) return false;
    for (int d = 1; d < m_frames; ++d)
        for (int m : m_modes)
            if (needs(m, (t0 + d) % m_frames, true)) {
                w = {m, (t0 + d) % m_frames, 1.0 / m_divisor};
                return true;
            }
    return false;
}

void ViewRenderer::loop() {
    // Below the UI thread: a busy renderer must not cost the UI its frame rate.
    setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 10);
    while (true) {
        Work w;
        {
            std::unique_lock<std::mutex> lk(m_mutex);
            m_cv.wait(lk, [&] { return m_quit || next_work(w); });
            if (m_quit) break;
        }
        try {
            render(w);
        } catch (const std::exception& e) {  // the project cannot be read: stop until reopened
            std::lock_guard<std::mutex> lk(m_mutex);
            m_error = e.what();
            m_failed = true;
        }
    }
    m_gpu.reset();  // its GL objects, on the context they were made in
    if (m_offscreen) glfwMakeContextCurrent(nullptr);
}

PreviewBackend& ViewRenderer::preview() {
    const Backend b = m_backend;
    const bool gpu = m_offscreen && m_gpu_error.empty() && b != Backend::Cpu;
    if (gpu && !m_gpu) {
        try {
            glfwMakeContextCurrent(m_offscreen);
            m_gpu = make_gl_preview();
        } catch (const std::exception& e) {
            m_gpu_error = e.what();
            std::lock_guard<std::mutex> lk(m_mutex);
            m_error = "the GLSL preview is unavailable, the CPU renders it: " + m_gpu_error;
        }
    }
    if (gpu && m_gpu) {
        m_gpu->set_quality(m_quality);
        return *m_gpu;
    }
    if (!m_cpu) m_cpu = make_cpu_preview(std::max(1u, std::thread::hardware_concurrency()));
    return *m_cpu;
}

// The fit's layers at `frame`, from the worker (which renders them between two fit steps).
std::shared_ptr<const FitWorker::ViewFrame> ViewRenderer::layers(int frame,
                                                                 uint64_t maps_generation) {
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        if (maps_generation != m_layers_generation) {
            m_layers.clear();
            m_layers_generation = maps_generation;
        }
        auto it = m_layers.find(frame);
        if (it != m_layers.end()) return it->second;
    }
    auto fut = m_worker.frame_async(frame);
    while (fut.wait_for(std::chrono::milliseconds(50)) != std::future_status::ready) {
        std::lock_guard<std::mutex> lk(m_mutex);
        if (m_quit) return nullptr;  // the worker may be preparing for minutes: do not wait
    }
    std::optional<FitWorker::ViewFrame> v = fut.get();
    if (!v) return nullptr;
    auto p = std::make_shared<const FitWorker::ViewFrame>(std::move(*v));
    std::lock_guard<std::mutex> lk(m_mutex);
    if (maps_generation != m_layers_generation) return p;  // the atlases changed meanwhile
    size_t bytes = 0;
    for (auto& [t, l] : m_layers) bytes += layer_bytes(*l);
    if (bytes + layer_bytes(*p) > kLayersBytes) m_layers.clear();
    m_layers[frame] = p;
    return p;
}

void ViewRenderer::render(const Work& w) {
    std::shared_ptr<const ViewScene> scene;
    std::string dir;
    uint64_t epoch;
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        scene = m_scene_ptr;
        dir = m_dir;
        epoch = m_epoch;
    }
    if (!m_source || m_source_dir != dir) {
        m_source = std::make_unique<FrameSource>(dir);
        m_source_dir = dir;
        std::lock_guard<std::mutex> lk(m_mutex);
        m_layers.clear();
    }
    if (w.mode < 0) {  // the layers alone, for click-to-focus in a mode that shows none
        if (scene->fitted) layers(w.frame, scene->maps_generation);
        return;
    }
    const ViewModeInfo& mode = view_modes()[w.mode];
    const double t0 = now_ms();
    Image input;
    try {
        input = m_source->linear(w.frame);
    } catch (const std::exception& e) {  // a frame the cache lost: black, said once
        input = Image(m_source->width(), m_source->height(), 3, 0.0f);
        std::lock_guard<std::mutex> lk(m_mutex);
        m_error = e.what();
    }
    std::shared_ptr<const FitWorker::ViewFrame> view;
    if (mode.needs_fit && scene->fitted) view = layers(w.frame, scene->maps_generation);
    std::shared_ptr<const FitWorker::ViewFrame> scaled = view;
    int divisor = 1;
    for (; w.scale * divisor < 0.99; divisor *= 2) {
        input = half(input);
        if (scaled) scaled = std::make_shared<const FitWorker::ViewFrame>(half(*scaled));
    }
    auto f = std::make_shared<RenderedFrame>();
    f->mode = w.mode;
    f->frame = w.frame;
    f->generation = mode.needs_fit ? scene->generation : 0;
    {
        std::lock_guard<std::mutex> lk(m_mutex);
        f->divisor = m_divisor;
        f->full = divisor == m_divisor;
    }
    f->view = view;
    Image img;
    try {
        img = mode.render(ModeInput{w.frame, input, scaled.get(), *scene, w.scale, preview()});
    } catch (const std::exception& e) {
        img = input;
        f->full = true;  // not again for this scene: the error is said once
        std::lock_guard<std::mutex> lk(m_mutex);
        m_error = e.what();
    }
    f->width = img.width;
    f->height = img.height;
    f->rgba = to_rgba8(img);
    f->hash = fnv1a(f->rgba);
    const double ms = now_ms() - t0;
    std::lock_guard<std::mutex> lk(m_mutex);
    if (epoch != m_epoch) return;  // another project opened meanwhile
    if (f->full && f->divisor == m_divisor) m_full_ms[w.mode] = ms;
    store(std::move(f));
}

void ViewRenderer::store(std::shared_ptr<RenderedFrame> f) {
    auto& slot = m_cache[{f->mode, f->frame}];
    if (slot) m_cache_bytes -= slot->rgba.size();
    m_cache_bytes += f->rgba.size();
    slot = std::move(f);
    evict();
}

// Over budget: drop pictures of older scenes first, then those farthest after the playhead.
void ViewRenderer::evict() {
    while (m_cache_bytes > kCacheBytes && m_cache.size() > 1) {
        auto worst = m_cache.end();
        long worst_score = -1;
        for (auto it = m_cache.begin(); it != m_cache.end(); ++it) {
            const RenderedFrame& f = *it->second;
            const bool stale = view_modes()[f.mode].needs_fit && f.generation != m_scene.generation;
            const long ahead = ((f.frame - m_playhead) % m_frames + m_frames) % m_frames;
            const long score = ahead + (stale ? 1000000 : 0);
            if (score > worst_score) worst_score = score, worst = it;
        }
        m_cache_bytes -= worst->second->rgba.size();
        m_cache.erase(worst);
    }
}

}  // namespace refocus
